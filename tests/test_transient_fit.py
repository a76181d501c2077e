"""The steady-state phasor from records that still hold the transient (analysis/signals/transient_fit.py,
app/transient_line.py), against analytic responses and an independent integrator."""
import numpy as np
import pytest
import scipy.integrate

from analysis.signals.transient_fit import fit_transient, free_response_poles
from app.campaign.acquisition import Record
from app.campaign.transient_line import TransientLines

FS = 512.0
F_LINE = 7.0
POLES = np.array([-0.4 + 2j * np.pi * 6.6, -1.1 + 2j * np.pi * 13.9])   # close to the line: a hard case
FORCED = np.array([0.3 - 0.2j, 1.0 + 0.5j])                             # sine-convention phasors, 2 channels


def analytic(t, noise=0.0, rng=None):
    """Forced sine plus a free response ten times stronger, per channel (t from the phasor origin)."""
    tau = t - t[0]
    y = np.empty((len(t), 2))
    for c in range(2):
        y[:, c] = np.imag(FORCED[c] * np.exp(2j * np.pi * F_LINE * t))
        for k, s in enumerate(POLES):
            y[:, c] += (10.0 / (k + 1)) * np.exp(s.real * tau) * np.cos(s.imag * tau + c + k)
    if noise:
        y += noise * rng.standard_normal(y.shape)
    return y


def test_noise_free_phasor_is_exact_from_poles_two_percent_off():
    t = np.arange(int(10 * FS / F_LINE)) / FS - 5 / F_LINE      # origin mid-window, as a line's last record
    fit = fit_transient(t, analytic(t), F_LINE, POLES * 1.02, n_harmonics=2)
    assert np.allclose(fit.phasors[1], FORCED, rtol=0, atol=1e-9)
    assert np.allclose(fit.poles, POLES, rtol=1e-9)
    assert np.all(np.abs(fit.phasors[2]) < 1e-9)


def test_phasor_std_is_consistent_with_the_noise_over_many_seeds():
    t = np.arange(int(10 * FS / F_LINE)) / FS
    z = []
    for seed in range(30):
        rng = np.random.default_rng(seed)
        fit = fit_transient(t, analytic(t, 0.05, rng), F_LINE, POLES * 1.01, n_harmonics=1)
        z.append(np.abs(fit.phasors[1] - FORCED) ** 2 / fit.std[1] ** 2)
    # E|dY|^2 / std^2 = 1 for every channel; 60 draws of a chi-square(2)/2: the mean within about +-0.35
    assert 0.65 < np.mean(z) < 1.4


def test_matrix_pencil_finds_the_poles_of_a_free_response_and_nothing_in_noise():
    t = np.arange(600) / FS
    free = analytic(t) - np.imag(FORCED[None, :] * np.exp(2j * np.pi * F_LINE * t)[:, None])
    assert np.allclose(free_response_poles(free, FS), POLES, rtol=1e-6)
    noise = np.random.default_rng(1).standard_normal((600, 2))
    assert len(free_response_poles(noise, FS)) == 0


# ----- against an independent integrator: a 2-DOF structure from rest under a sine force ---------------
M = np.diag([1.0, 0.5])
K = np.array([[6000.0, -2000.0], [-2000.0, 2000.0]])
C = 0.5 * M + 2e-4 * K
FORCE = 2.0


def integrate(law, frequency, periods, dofs=2):
    """Accelerations and force sampled at FS from rest, by solve_ivp at tight tolerances (RK45, not the
    project's simulator). ``law(x)`` is an extra restoring force on DOF 0."""
    Minv = np.linalg.inv(M[:dofs, :dofs])
    w = 2 * np.pi * frequency

    def rhs(t, s):
        x, v = s[:dofs], s[dofs:]
        f = np.zeros(dofs)
        f[0] = FORCE * np.sin(w * t) - law(x[0])
        return np.concatenate([v, Minv @ (f - C[:dofs, :dofs] @ v - K[:dofs, :dofs] @ x)])

    t = np.arange(int(round(periods * FS / frequency))) / FS
    sol = scipy.integrate.solve_ivp(rhs, (0, t[-1]), np.zeros(2 * dofs), t_eval=t, rtol=1e-10, atol=1e-12,
                                    method="DOP853")
    acc = np.array([rhs(ti, si)[dofs:] for ti, si in zip(t, sol.y.T)])
    return np.column_stack([FORCE * np.sin(w * t), acc])


def records(data, frequency, periods_per_record=5):
    n = int(round(periods_per_record * FS / frequency))
    return [Record(data[i:i + n], i, FS, False) for i in range(0, len(data) - n + 1, n)]


def lines(tolerance=2e-3):
    return TransientLines(FS, 5, tolerance, force_index=0, sensor_index=[1, 2])


def test_linear_structure_from_rest_gives_the_analytic_receptance_within_two_records():
    f = 9.0
    data = integrate(lambda x: 0.0, f, 20)
    meter = lines()
    meter.restart()
    recs = records(data, f)
    # the poles from the start of the free response (what a line that waited would hand on)
    for rec in recs:
        meter.add(rec, f)
    meter.learn(f, _steady_harmonics(data[-recs[-1].data.shape[0]:], f))
    exact = np.linalg.eigvals(np.block([[np.zeros((2, 2)), np.eye(2)],
                                        [-np.linalg.solve(M, K), -np.linalg.solve(M, C)]]))
    exact = exact[exact.imag > 0]
    exact = exact[np.argsort(exact.imag)]
    # seeds: the line's last record still holds some transient, so its harmonics are not quite the steady ones
    assert np.allclose(meter.poles, exact, rtol=2e-2)
    meter.restart()
    estimates = [meter.add(rec, f) for rec in recs[:2]]
    assert estimates[-1].accepted, estimates[-1].reason
    estimate = next(e for e in estimates if e.accepted)
    w = 2 * np.pi * f
    H = np.linalg.solve(K - w**2 * M + 1j * w * C, [1.0, 0.0])
    # the phasors are at the first sample of the last record; the force sine started at t = 0
    frf = estimate.phasors[1, 1:] / (-w**2 * estimate.phasors[1, 0])
    assert np.allclose(frf, H, rtol=1e-6)
    assert estimate.frf_std < 1e-5
    assert np.allclose(meter.poles, exact, rtol=1e-6)        # refined by the accepted fit, handed on


def _steady_harmonics(data, f):
    from analysis.signals.harmonics import harmonics_at
    return harmonics_at(data, FS, f, 5).amplitudes


@pytest.mark.slow
def test_a_hardening_spring_is_refused_and_the_reason_said():
    """A Duffing oscillator near its jump, from rest: the modes fitted to a line of the linear structure do not
    hold, and its phasor sequence, far from the orbit over six records, does not yet settle on a limit."""
    f = 8.0
    law = lambda x: 4e7 * x**3   # noqa: E731  (hardening: 0.75 k3 X^2 several times k at X ~ 1e-2 m)
    data = integrate(law, f, 30)
    meter = lines()
    meter.poles = np.array([-0.6 + 2j * np.pi * 7.1, -1.6 + 2j * np.pi * 14.2])
    meter.restart()
    decisions = [meter.add(rec, f) for rec in records(data, f)[:6]]
    made = [d for d in decisions if d is not None]
    assert made and not any(d.accepted for d in made)
    assert all(("harmonics" in d.reason) or ("do not describe" in d.reason) or ("changes" in d.reason)
               or ("phasor" in d.reason) for d in made)
    assert "harmonics" in made[0].reason


def test_a_channel_held_at_zero_leaves_the_fit_finite():
    """A DOF friction holds reads exactly zero: its phasors are zero with a finite std, the others unchanged."""
    t = np.arange(int(10 * FS / F_LINE)) / FS
    y = analytic(t)
    with_zero = np.column_stack([y, np.zeros(len(t))])
    a = fit_transient(t - t[-1], y, F_LINE, POLES)
    b = fit_transient(t - t[-1], with_zero, F_LINE, POLES)
    assert np.all(np.isfinite(b.std)) and np.all(b.phasors[:, 2] == 0)
    assert np.allclose(b.phasors[:, :2], a.phasors, rtol=1e-9, atol=1e-12)


def test_no_poles_no_fit():
    meter = lines()
    meter.restart()
    t = np.arange(int(20 * FS / F_LINE)) / FS
    assert all(meter.add(rec, F_LINE) is None for rec in records(analytic(t), F_LINE))
    assert meter.reason == "no poles known yet"


@pytest.mark.parametrize("value, message", [('"fast"', "must be one of steady, transient"),
                                            ('"transient"\nfixed_periods = 300', "cannot be combined")])
def test_plan_refuses_a_bad_settle_method_naming_the_field(value, message):
    import tomllib
    from analysis.common.errors import InputError
    from app.campaign.plan import parse_plan
    text = (f"[settle]\nmethod = {value}\n[[stepped_sine]]\nforce = 0.5\nstart = 5.0\nstop = 6.0\nstep = 0.5\n"
            "[limits]\nmax_force = 5.0\nmax_acceleration = 100.0\n")
    with pytest.raises(InputError) as err:
        parse_plan(tomllib.loads(text), text, "p.toml")
    assert "[settle].method" in str(err.value) and message in str(err.value)
