"""The Brake-Reuss beam's measured stepped sine (ForcedFrequencyResponses.mat) in contactid's CSV long format.

    python docs/examples/brb_to_csv.py ../shared/realdata/brb/ForcedFrequencyResponses.mat brb.csv

Each level holds, per line, the fundamental amplitudes of the drive-point acceleration (m/s^2) and of the force
(N) and the phase of the acceleration against the force (rad). The receptance is X/F = -A/(w^2 F) (a harmonic
acceleration is -w^2 times its displacement). Nothing else is changed: the force sign is left as measured (the
import checks it), the force measured at each line goes in ``force_amplitude_n``, the force-controlled levels
keep their nominal force in ``force_n``, and the response-controlled ones name the acceleration they held at the
drive point (``control_target``, m/s^2). The accelerometer sits at the drive point: DOF ``x1``.
"""
from __future__ import annotations

import csv
import sys

import numpy as np
import scipy.io

DOF = "x1"
FORCE_LEVELS = (0.2, 0.5, 1.0, 1.5)                                  # N, nominal (README.md)
RESPONSE_LEVELS = (5.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0)    # m/s^2 at the drive point
COLUMNS = ["frequency_hz", "force_n", "dof", "re", "im", "force_amplitude_n", "control_dof", "control_quantity",
           "control_target"]


def rows(mat_path: str):
    """The CSV rows of every level, force-controlled first."""
    data = scipy.io.loadmat(mat_path, squeeze_me=True, struct_as_record=False)["FRdata"]
    levels = [(level, f"{force:g}", "", "", "") for level, force in zip(data.ForceControl, FORCE_LEVELS)]
    levels += [(level, "", DOF, "acceleration", f"{target:g}")
               for level, target in zip(data.ResponseControl, RESPONSE_LEVELS)]
    for level, force_n, control_dof, quantity, target in levels:
        if str(level.units).replace(" ", "") != "Hz,N,m/s^2,rad":
            raise ValueError(f"{mat_path}: units {level.units!r}, not 'Hz, N, m/s^2, rad'")
        w = 2 * np.pi * np.asarray(level.frequency, float)
        accelerance = np.asarray(level.amplitude, float) * np.exp(1j * np.asarray(level.phase, float)) \
            / np.asarray(level.force, float)
        receptance = -accelerance / w ** 2
        for f, h, force in zip(level.frequency, receptance, level.force):
            yield [repr(float(f)), force_n, DOF, repr(float(h.real)), repr(float(h.imag)), repr(float(force)),
                   control_dof, quantity, target]


def write_csv(mat_path: str, csv_path: str) -> None:
    with open(csv_path, "w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(COLUMNS)
        out.writerows(rows(mat_path))


if __name__ == "__main__":
    write_csv(sys.argv[1], sys.argv[2])
