"""An SDOF rig with a Jenkins joint at its drive point, integrated by RK4 here (independent of the project's
simulator and harmonic balance): the measured stepped sine a controller would give, with the force per line.

    m x'' + c x' + k x + f_j = F sin(w t),   f_j = kt (x - z), |f_j| <= fs (the slider z moves to keep it so)

Every line starts from the stuck linear steady state and is integrated for ``periods`` periods; the fundamental
of the last period is the measurement (``x = Im(X exp(jwt))``, receptance X / F).
"""
from __future__ import annotations

import csv
from dataclasses import dataclass

import numpy as np

M, K, C = 1.0, 15791.367, 2.884        # kg, N/m (20 Hz alone), N s/m (1 % of critical with the stuck joint)
KT, FS = 5000.0, 0.05                  # N/m, N: the Jenkins joint at x1
STEPS = 256                            # RK4 steps per period


@dataclass
class Level:
    frequency_hz: np.ndarray
    force: np.ndarray                  # N per line (the force measured)
    receptance: np.ndarray             # m/N


def stuck_frequency_hz() -> float:
    return float(np.sqrt((K + KT) / M) / (2 * np.pi))


def stuck_damping() -> float:
    return float(C / (2 * np.sqrt((K + KT) * M)))


def drifting(nominal: float, n: int, drift: float, phase: float = 0.0) -> np.ndarray:
    """A controller's force around its target: within +-drift of it, as measured line by line."""
    return nominal * (1 + drift * np.sin(2 * np.pi * np.arange(n) / 17.0 + phase))


def measure(frequency_hz: np.ndarray, force: np.ndarray, periods: int = 100) -> np.ndarray:
    """Receptance of the fundamental at each line (vectorised over lines; each line integrated in its own
    dimensionless time tau = w t)."""
    w = 2 * np.pi * np.asarray(frequency_hz, float)
    F = np.asarray(force, float)
    H0 = 1.0 / (K + KT - M * w ** 2 + 1j * C * w)                 # stuck: start on the linear steady state
    X0 = H0 * F
    x, v = X0.imag.copy(), w * X0.real.copy()                      # x = a sin + b cos, X = a + jb
    z = np.zeros_like(x)
    h = 2 * np.pi / STEPS

    def joint(xx, z):
        return np.clip(KT * (xx - z), -FS, FS)

    def rhs(tau, x, v, z):
        acc = (F * np.sin(tau) - C * v - K * x - joint(x, z)) / M
        return v / w, acc / w                                      # d/dtau

    tau = 0.0
    last = np.zeros((STEPS, len(w)))
    for n in range(periods * STEPS):
        k1 = rhs(tau, x, v, z)
        k2 = rhs(tau + h / 2, x + h / 2 * k1[0], v + h / 2 * k1[1], z)
        k3 = rhs(tau + h / 2, x + h / 2 * k2[0], v + h / 2 * k2[1], z)
        k4 = rhs(tau + h, x + h * k3[0], v + h * k3[1], z)
        x = x + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        v = v + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        f = KT * (x - z)
        z = np.where(np.abs(f) > FS, x - np.sign(f) * FS / KT, z)     # the slider moves: |force| = fs
        tau += h
        if n >= (periods - 1) * STEPS:
            last[n - (periods - 1) * STEPS] = x
    t = h * np.arange(1, STEPS + 1)
    a = 2 / STEPS * (last * np.sin(t)[:, None]).sum(axis=0)
    b = 2 / STEPS * (last * np.cos(t)[:, None]).sum(axis=0)
    return (a + 1j * b) / F


def campaign(nominal_forces, frequency_hz, drift: float = 0.0, periods: int = 100) -> list[Level]:
    """One rising sweep per nominal force, the force drifting by +-drift around it."""
    f = np.asarray(frequency_hz, float)
    forces = [drifting(F0, len(f), drift, phase=i) for i, F0 in enumerate(nominal_forces)]
    # every line of every level integrated at once: the lines are independent, and a step costs the same
    receptances = np.split(measure(np.tile(f, len(forces)), np.concatenate(forces), periods), len(forces))
    return [Level(f, force, h) for force, h in zip(forces, receptances)]


def response_controlled(targets, frequency_hz, iterations: int = 7, periods: int = 100) -> list[Level]:
    """Levels holding the displacement amplitude at x1 (m) as a response controller does: at each line the force
    is corrected from the linear guess by secant steps on log |X| against log F (|X| grows with F), ``iterations``
    times; what is recorded is the last force and its response."""
    f = np.asarray(frequency_hz, float)
    # every line of every level corrected at once (the lines are independent)
    lines = np.tile(f, len(targets))
    target = np.repeat(np.asarray(targets, float), len(f))
    w = 2 * np.pi * lines
    linear = np.abs(1.0 / (K + KT - M * w ** 2 + 1j * C * w))
    log_f = np.log(target / linear)
    log_x = np.log(np.abs(measure(lines, np.exp(log_f), periods)) * np.exp(log_f))
    slope = np.ones_like(lines)
    for _ in range(iterations - 1):
        step = (np.log(target) - log_x) / slope
        new_f = log_f + step
        new_x = np.log(np.abs(measure(lines, np.exp(new_f), periods)) * np.exp(new_f))
        moved = np.abs(step) > 1e-9
        slope = np.where(moved, np.clip((new_x - log_x) / np.where(moved, step, 1.0), 0.2, 5.0), slope)
        log_f, log_x = new_f, new_x
    force = np.exp(log_f)
    receptance = measure(lines, force, periods)
    return [Level(f, fl, h) for fl, h in zip(np.split(force, len(targets)), np.split(receptance, len(targets)))]


def write_csv(path, levels: list[Level], nominal_forces, per_line_force: bool = True,
              response_targets=None) -> None:
    """The CSV long format (docs/import.md), DOF x1, with or without the force measured at each line; with
    ``response_targets`` (m) the levels are response-controlled (``nominal_forces`` unused)."""
    columns = ["frequency_hz", "force_n", "dof", "re", "im"] + (["force_amplitude_n"] if per_line_force else [])
    if response_targets is not None:
        columns += ["control_dof", "control_quantity", "control_target"]
    with open(path, "w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(columns)
        for i, level in enumerate(levels):
            level_columns = [repr(float(nominal_forces[i]))] if response_targets is None else [""]
            held = [] if response_targets is None else ["x1", "displacement", repr(float(response_targets[i]))]
            for f, h, force in zip(level.frequency_hz, level.receptance, level.force):
                row = [repr(float(f)), *level_columns, "x1", repr(float(h.real)), repr(float(h.imag))]
                out.writerow(row + ([repr(float(force))] if per_line_force else []) + held)
