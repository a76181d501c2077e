"""From a fitted model to what a test would measure: harmonic balance (``harmonic_balance``), the model against the
measurement (``comparison``), natural frequency and damping against amplitude (``backbone``), and one element's
laws refined against the FRFs where the kbar leaves a size open (``frf_refinement``).

May import: ``common``, ``laws``, ``mechanics``, ``signals``, ``identification``, ``fitting``.
"""
