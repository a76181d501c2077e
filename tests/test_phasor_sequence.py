"""The limit of a sequence of harmonic phasors (analysis/signals/phasor_sequence.py) and the stepped-sine lines with
harmonics taken from it (app/campaign/transient_line.py): against sequences written from the model, a steady sine
written from its phasors, and nonlinear oscillators integrated by solve_ivp (not the project's simulator) until
they settle."""
import numpy as np
import pytest
import scipy.integrate

from analysis.signals.phasor_sequence import fit_sequence, window_phasors
from app.campaign.acquisition import Record
from app.campaign.transient_line import TransientLines

FS = 512.0


def test_limit_and_multipliers_of_a_written_sequence_and_its_std_covers_the_error():
    """P_n = P_inf + a1 mu1^n + a2 mu2^n + noise, 8 phasors: the limit within its std as often as a normal error
    is, and the multipliers found."""
    mu = np.array([0.85 * np.exp(0.4j), 0.7 * np.exp(-1.1j)])
    z = []
    for seed in range(200):
        rng = np.random.default_rng(seed)
        limit = rng.normal(size=8) + 1j * rng.normal(size=8)
        a = 3 * (rng.normal(size=(2, 8)) + 1j * rng.normal(size=(2, 8)))
        n = np.arange(30)[:, None]
        noise = 1e-3
        P = limit + (mu[0] ** n) * a[0] + (mu[1] ** n) * a[1]
        P = P + noise * (rng.normal(size=P.shape) + 1j * rng.normal(size=P.shape)) / np.sqrt(2)
        fit = fit_sequence(P, noise)
        assert fit.converging
        assert np.allclose(np.sort_complex(fit.multipliers), np.sort_complex(mu), atol=1e-3)
        z.append(np.abs(fit.limit - limit) / fit.std)
    z = np.concatenate(z)
    # |complex normal| / std: 3 std holds about 99 % of them; a std too small by x2 would leave 11 % outside
    assert np.mean(z <= 3) > 0.97, np.mean(z <= 3)


def test_second_order_terms_beyond_the_pencils_order_are_fitted_as_products_of_its_multipliers():
    """P_n with four modes' terms (8 multipliers, the pencil's bound) and the second-order terms of the largest,
    (mu mu*)^n and mu^2n, mu*^2n (2): the pencil has no room for them, and without them the limit is outside 3 of
    its standard deviations for most phasors; with the products it is within them as often as a normal error is
    within 3 standard deviations (a std too small by x2 would leave 11 % outside)."""
    first = np.array([r * np.exp(s * 1j * a) for r, a in [(0.97, 0.7), (0.9, 1.4), (0.85, 2.1), (0.8, 0.3)]
                      for s in (1, -1)])
    size = np.array([30, 30, 10, 10, 5, 5, 5, 5])
    second = np.array([abs(first[0]) ** 2, first[0] ** 2, first[1] ** 2])
    second_size = np.array([3.0, 1.0, 1.0])
    z = {False: [], True: []}
    for seed in range(100):
        rng = np.random.default_rng(seed)

        def normal(*shape):
            return rng.normal(size=shape) + 1j * rng.normal(size=shape)
        n = np.arange(60)[:, None]
        limit = 50 * normal(6)
        P = (limit + sum(m ** n * a * normal(6) for m, a in zip(first, size))
             + sum(m ** n * a * normal(6) for m, a in zip(second, second_size)) + normal(60, 6) / np.sqrt(2))
        for products in z:
            fit = fit_sequence(P, 1.0, products=products)
            z[products].append(np.abs(fit.limit - limit) / fit.std)
    assert np.mean(np.concatenate(z[False]) <= 3) < 0.6
    assert np.mean(np.concatenate(z[True]) <= 3) > 0.95


def test_a_sequence_that_does_not_decay_is_not_converging():
    """An undamped beat (|mu| = 1) has no limit to extrapolate to."""
    n = np.arange(40)[:, None]
    P = 1.0 + 0.5 * np.exp(0.3j * n) * np.ones((1, 4))
    assert not fit_sequence(P, 1e-6).converging
    assert fit_sequence(P[:3], 1e-6) is None                  # too short to hold a multiplier


def test_window_phasors_of_a_steady_sine_are_its_phasors_at_the_origin():
    """Harmonics of a sine at a frequency with a fraction of a sample per period: every window gives the
    written phasors, referred to the sample named as origin."""
    f, Y = 9.37, np.array([0.2, 1.0 - 0.5j, 0.0, 0.03j, 0.0, 0.0])
    t = np.arange(2000) / FS
    y = Y[0].real + sum(np.imag(Y[h] * np.exp(2j * np.pi * f * h * t)) for h in range(1, 6))
    origin = 1500
    P, noise = window_phasors(np.column_stack([y, 2 * y]), FS, f, 2, 5, origin)
    at_origin = Y * np.exp(2j * np.pi * f * np.arange(6) * origin / FS)
    assert P.shape == (int((2000 - round(2 * FS / f)) // (2 * FS / f)) + 1, 6, 2)
    assert np.allclose(P[:, :, 0], at_origin, atol=1e-12)
    assert np.allclose(P[:, :, 1], 2 * at_origin, atol=1e-12)
    assert np.all(noise < 1e-12)


# ----- nonlinear oscillators, integrated independently ---------------------------------------------------------
M, K, C, FORCE = 1.0, 3947.8, 1.5, 0.5        # the hardening rig's oscillator (tests/rigs/hardening.toml)


def duffing(x):
    return 4.0e7 * x**3


def friction(v):
    return 0.05 * np.tanh(v / 2e-4)             # Coulomb friction of 10 % of the force, smoothed at 0.2 mm/s


def switched(law, velocity_law, f1, f2, settle_periods, periods):
    """Force and acceleration at FS after the drive moves from f1 (settled for ``settle_periods``) to f2 with
    continuous phase, as a sweep's next line; DOP853 at tight tolerances, and a DAQ's noise added (1e-4 N,
    1e-3 m/s^2 rms)."""
    def rhs(w, phase):
        def f(t, s):
            x, v = s
            force = FORCE * np.sin(w * t + phase)
            return [v, (force - C * v - K * x - law(x) - velocity_law(v)) / M]
        return f
    w1, w2 = 2 * np.pi * f1, 2 * np.pi * f2
    T1 = settle_periods / f1
    first = scipy.integrate.solve_ivp(rhs(w1, 0.0), (0, T1), [0.0, 0.0], method="DOP853", rtol=1e-10,
                                      atol=1e-13)
    t = np.arange(int(round(periods * FS / f2))) / FS
    phase = w1 * T1
    second = scipy.integrate.solve_ivp(rhs(w2, phase), (0, t[-1]), first.y[:, -1], t_eval=t, method="DOP853",
                                       rtol=1e-10, atol=1e-13)
    acc = np.array([rhs(w2, phase)(ti, si)[1] for ti, si in zip(t, second.y.T)])
    noise = np.random.default_rng(7).standard_normal((len(t), 2)) * [1e-4, 1e-3]
    return np.column_stack([FORCE * np.sin(w2 * t + phase), acc]) + noise


def records(data, frequency, periods_per_record=5):
    n = int(round(periods_per_record * FS / frequency))
    return [Record(data[i:i + n], i, FS, False) for i in range(0, len(data) - n + 1, n)]


def first_taken(meter, data, frequency):
    """The records of ``data`` fed to ``meter`` one by one until one is taken: ((record, estimate) of the first
    taken, or None), and the estimates of the records before it (None where a record gave none)."""
    refused = []
    for rec in records(data, frequency):
        estimate = meter.add(rec, frequency)
        if estimate is not None and estimate.accepted:
            return (rec, estimate), refused
        refused.append(estimate)
    return None, refused


def settled_frf(data, frequency, origin):
    """The accelerance of the last two periods, the steady state the line converges to, at sample ``origin``."""
    P, _ = window_phasors(data[-2 * int(round(2 * FS / frequency)):], FS, frequency, 2, 5,
                          origin - (len(data) - 2 * int(round(2 * FS / frequency))))
    return P[-1, 1, 1] / P[-1, 1, 0]


@pytest.mark.slow
@pytest.mark.parametrize("law, velocity_law, f1, f2", [
    (duffing, lambda v: 0.0, 9.8, 10.0),         # THD 2e-3, the multipliers moved by the amplitude
    (duffing, lambda v: 0.0, 10.0, 10.2),        # THD 5e-3, further up the branch
    (lambda x: 0.0, friction, 9.4, 9.6),         # sticking at the turning points
], ids=["duffing-10.0", "duffing-10.2", "friction-9.6"])
def test_a_line_with_harmonics_is_taken_from_its_sequence_within_the_tolerance(law, velocity_law, f1, f2):
    """The fit of modes refuses the line (harmonics); the phasor sequence takes it once its limit is precise and
    consistent, within the tolerance of the oscillator's settled response, in fewer periods than settling takes."""
    tolerance = 2e-3
    data = switched(law, velocity_law, f1, f2, 300, 300)
    meter = TransientLines(FS, 5, tolerance, force_index=0, sensor_index=[1])
    meter.poles = np.array([-0.75 + 1j * np.sqrt(K / M - 0.75**2)])     # the linear oscillator's pole
    meter.restart()
    taken, refused = first_taken(meter, data, f2)
    assert all(e is None or e.reason for e in refused), "a refusal says why"
    assert taken is not None, meter.reason
    rec, estimate = taken
    assert 2 * np.linalg.norm(estimate.phasors[2:, 1]) > tolerance * abs(estimate.phasors[1, 1])   # harmonics
    frf = estimate.phasors[1, 1] / estimate.phasors[1, 0]
    truth = settled_frf(data, f2, rec.first_sample)
    last = rec.data[:, :]
    assert abs(frf / truth - 1) <= tolerance
    assert 3 * estimate.frf_std <= tolerance
    periods = (rec.first_sample + len(last)) * f2 / FS
    # the record the line was taken at still holds more of the transient than the tolerance
    P, _ = window_phasors(rec.data, FS, f2, 2, 5, 0)
    assert periods <= 100
    assert abs((P[0, 1, 1] / P[0, 1, 0]) / truth - 1) > tolerance or periods <= 10


def test_a_linear_line_whose_transient_the_poles_known_do_not_describe_is_taken_from_its_sequence():
    """A linear line with a strong transient of a mode the poles known miss: the fit of modes leaves that transient
    in the harmonics of its first record and the line goes to its sequence, which takes it once its limit is
    within its error budget, within the tolerance of the settled response. The limit's harmonics are those of a
    linear line, but not yet certainly so (3 standard deviations larger they are not): the fit of modes, with
    poles that miss the mode, never took a record of it."""
    tolerance, f = 2e-3, 9.4
    data = switched(lambda x: 0.0, lambda v: 0.0, 6.0, f, 5, 80)         # a strong transient
    meter = TransientLines(FS, 5, tolerance, force_index=0, sensor_index=[1])
    meter.poles = np.array([-0.2 + 2j * np.pi * 6.0])                    # not the oscillator's
    meter.restart()
    taken, refused = first_taken(meter, data, f)
    reasons = [e.reason if e is not None else "" for e in refused]
    assert taken is not None, reasons
    assert reasons[0].startswith("harmonics")
    assert all(r == "" or r.startswith("phasor sequence's limit uncertain") for r in reasons[1:]), reasons
    rec, estimate = taken
    assert 2 * np.linalg.norm(estimate.phasors[2:, 1]) <= tolerance * abs(estimate.phasors[1, 1])   # linear
    truth = settled_frf(data, f, rec.first_sample)
    assert abs(estimate.phasors[1, 1] / estimate.phasors[1, 0] / truth - 1) <= tolerance
    first = window_phasors(data[:rec.first_sample], FS, f, 2, 5, 0)[0][0]
    assert abs(first[1, 1] / first[1, 0] / truth - 1) > 10 * tolerance     # the transient the line began with


def swept(law, lines):
    """Force and acceleration at FS of the last of ``lines`` ((Hz, periods) pairs), the drive stepped from line
    to line with continuous phase from rest, as a sweep measures them; DOP853 at tight tolerances and the noise
    of :func:`switched`."""
    state, phase = [0.0, 0.0], 0.0
    for number, (f, periods) in enumerate(lines):
        w = 2 * np.pi * f

        def rhs(t, s, w=w, phase=phase):
            x, v = s
            return [v, (FORCE * np.sin(w * t + phase) - C * v - K * x - law(x)) / M]
        if number < len(lines) - 1:
            state = scipy.integrate.solve_ivp(rhs, (0, periods / f), state, method="DOP853", rtol=1e-10,
                                              atol=1e-13).y[:, -1]
            phase += w * periods / f
    t = np.arange(int(round(periods * FS / f))) / FS
    y = scipy.integrate.solve_ivp(rhs, (0, t[-1]), state, t_eval=t, method="DOP853", rtol=1e-10, atol=1e-13).y
    acc = np.array([rhs(ti, si)[1] for ti, si in zip(t, y.T)])
    noise = np.random.default_rng(7).standard_normal((len(t), 2)) * [1e-4, 1e-3]
    return np.column_stack([FORCE * np.sin(w * t + phase), acc]) + noise


@pytest.mark.slow
def test_a_line_past_a_jump_is_taken_within_the_tolerance_once_its_decay_is_fitted():
    """Up a Duffing oscillator's upper branch in 0.2 Hz steps to the line where it falls to the lower one: the
    decay between the branches is large and nonlinear (harmonics, then Floquet multipliers outside the unit
    circle); the line is taken once its sequence's limit is within its error budget, within the tolerance of
    the settled response. (The line waited for the whole decay to die before a limit without harmonics handed
    it to the fit of modes: 245 periods on the rig of benchmarks/transient_speed.py; 145 then.)"""
    tolerance, f = 2e-3, 11.0
    data = swept(duffing, [(10.0, 150), (10.2, 60), (10.4, 60), (10.6, 60), (10.8, 60), (f, 300)])
    meter = TransientLines(FS, 5, tolerance, force_index=0, sensor_index=[1])
    meter.poles = np.array([-0.75 + 1j * np.sqrt(K / M - 0.75**2)])     # the linear oscillator's pole
    meter.restart()
    taken, refused = first_taken(meter, data, f)
    reasons = [e.reason if e is not None else "" for e in refused]
    assert taken is not None, reasons
    assert reasons[0].startswith("harmonics")                           # the first record: the upper branch's
    rec, estimate = taken
    truth = settled_frf(data, f, rec.first_sample)
    assert abs(estimate.phasors[1, 1] / estimate.phasors[1, 0] / truth - 1) <= tolerance
    first = window_phasors(data[:rec.first_sample], FS, f, 2, 5, 0)[0][0]
    assert abs(first[1, 1] / first[1, 0] / truth - 1) > 1.0           # where the line started: the other branch
    assert (rec.first_sample + len(rec.data)) * f / FS <= 145


def test_a_limit_says_the_line_is_linear_only_where_its_harmonics_are_certainly_within_a_linear_lines():
    """The route to the fit of modes: a limit without harmonics whose harmonics, each 3 standard deviations
    larger, stay within the THD a linear line may show says the line is linear; the same limit with
    harmonics that uncertain, or one with harmonics, does not."""
    tolerance = 2e-3
    meter = TransientLines(FS, 5, tolerance, force_index=0, sensor_index=[1])
    limit = np.zeros((6, 2), complex)
    limit[1] = [1.0, 2.0 - 1.0j]
    certain, uncertain = np.full((6, 2), 1e-6), np.full((6, 2), 1e-3)
    assert meter._linear(limit, certain).startswith("no harmonics in the steady state")
    assert meter._linear(limit, uncertain) == ""          # 3 std of four harmonics: a THD up to 2.7e-3, over 1e-3
    distorted = limit.copy()
    distorted[3, 1] = 0.01
    assert meter._linear(distorted, certain) == ""


@pytest.mark.parametrize("length", [200, 273, 274, 275, 1000, 1001])
def test_windows_fit_inside_the_data_whatever_its_length(length):
    """Windows start at the sample nearest a whole number of periods: as many as end inside the data."""
    f = 9.37
    P, _ = window_phasors(np.ones((length, 2)), FS, f, 2, 5, 0)
    per_window, n = 2 * FS / f, int(np.ceil(2 * FS / f))
    assert round((len(P) - 1) * per_window) + n <= length < round(len(P) * per_window) + n
    assert np.allclose(P[:, 0, :], 1.0)


@pytest.mark.parametrize("last", [1, 5, 200])
def test_the_last_windows_are_the_same_windows_as_all_of_them_end_with(last):
    """``last`` keeps the windows where they are: the last so many of all, phasors and noise, at the same origin."""
    rng = np.random.default_rng(5)
    data = np.column_stack([np.sin(2 * np.pi * 9.37 * np.arange(3001) / FS), rng.normal(size=3001)])
    P, noise = window_phasors(data, FS, 9.37, 2, 5, 2500)
    P_last, noise_last = window_phasors(data, FS, 9.37, 2, 5, 2500, last=last)
    assert len(P_last) == min(last, len(P))
    assert np.array_equal(P_last, P[-last:]) and np.array_equal(noise_last, noise[-last:])
