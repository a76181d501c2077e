"""From a fitted model to what a test would measure: harmonic balance (``harmonic_balance``, with harmonics ``multiharmonic``), the model against the
measurement (``comparison``), natural frequency and damping against amplitude (``backbone``), one element's
laws refined against the FRFs where the kbar leaves a size open (``frf_refinement``), and a fitted model's
prediction of a session with nothing refitted, fitted levels told from held-out ones (``held_out``).

May import: ``common``, ``laws``, ``mechanics``, ``signals``, ``identification``, ``fitting``.
"""
