"""Estimators on measured signals: harmonics of a record (``harmonics``), the steady state of a record that still
holds its transient (``transient_fit``), H1/H2/Hv FRFs and coherence (``frf_estimation``), an FRF's noise
(``frf_noise``), the force per volt a shaker will give next (``drive_prediction``) and the modal fit
(``modal_fit``).

May import: ``common``.
"""
