"""Rig simulator: physics against analytic and exact references, sensors, generator, paper example."""
import math
from pathlib import Path

import numpy as np
import pytest
import scipy.signal
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from analysis.signals.harmonics import harmonics, sine_fit
from analysis.laws import LAWS
from analysis.mechanics.structures import Structure
from drivers.simulation import kernels
from drivers.simulation.rig import load_rig, parse_rig
from drivers.simulation import simulator
from drivers.simulation.simulator import _SINE_ROW, RigSimulator, SimulationError, _anti_alias_taps
from test_laws import iwan_lipschitz_excess
from paper_structure import PAPER_STRUCTURE

TWO_PI = 2 * math.pi


def sdof_rig(k, laws="", mass=1.0, damping=None, rate=512.0, extra=""):
    """A one-DOF rig: mass on a spring, an element of the given laws, force and accelerometer on it."""
    damping_line = f"damping = [[{damping!r}]]" if damping is not None else ""
    return parse_rig(f"""
name = "sdof"
[structure]
type = "lumped"
dofs = ["x"]
mass = [[{mass!r}]]
stiffness = [[{k!r}]]
{damping_line}
[[element]]
name = "contact"
dof = "x"
laws = [{laws}]
[excitation]
dof = "x"
[sensors]
dofs = ["x"]
[daq]
sample_rate = {rate!r}
acceleration_range = 1000.0
{extra}
""", "sdof.toml")


def steady_harmonics(sim, frequency, amplitude, settle, periods=10, n_harmonics=3):
    """Drive at a coherent frequency near ``frequency``, wait ``settle`` s, analyse whole periods."""
    n = int(round(periods * sim.sample_rate / frequency))
    frequency = periods * sim.sample_rate / n
    sim.set_sine(frequency, amplitude)
    sim.advance(int(settle * sim.sample_rate))
    return frequency, harmonics(sim.advance(n), sim.sample_rate, frequency, n_harmonics)


# --- linear response --------------------------------------------------------------
LINEAR_2DOF = """
name = "linear"
""" + PAPER_STRUCTURE + """rayleigh = [0.5, 0.005]
[[element]]
name = "spring"
between = ["x1", "x2"]
laws = [ { law = "linear", k = 50.0, c = 0.3 } ]
[excitation]
dof = "x2"
[sensors]
dofs = ["x1", "x2"]
[daq]
sample_rate = 256.0
acceleration_range = 20.0
"""


def test_linear_steady_state_matches_the_analytic_frf():
    rig = parse_rig(LINEAR_2DOF, "linear.toml")
    s = rig.structure
    e = rig.elements[0].vector(s)
    full = Structure(s.dofs, s.M, s.K + 50.0 * np.outer(e, e), s.C + 0.3 * np.outer(e, e))
    for f in (0.7, 1.27, 2.0, 2.8, 4.0):
        sim = RigSimulator(rig)
        sim.set_output(True)
        f, h = steady_harmonics(sim, f, 0.5, settle=60.0)
        w = TWO_PI * f
        measured = h.fundamental[1:] / h.fundamental[0]
        expected = -w**2 * full.frf(w, ["x2"])[0, :, 0]
        np.testing.assert_allclose(measured, expected, rtol=1e-4)


def test_reduced_beam_matches_the_full_linear_frf():
    """Truncation check: the reduction keeps the rig's linear FRFs below the cutoff."""
    rig = load_rig("paper-beam")
    s, model = rig.structure, rig.linear
    M, K, C = s.M.copy(), s.K.copy(), s.C.copy()
    a = s.index("A.w")
    M[a, a] += rig.shaker.armature_mass
    K[a, a] += rig.shaker.suspension_stiffness
    C[a, a] += rig.shaker.suspension_damping
    for el, k0 in zip(rig.elements, model.k0):
        e = el.vector(s)
        K += k0 * np.outer(e, e)
    full = Structure(s.dofs, M, K, C)
    w = TWO_PI * np.linspace(5.0, 200.0, 800)
    sensors = [s.index(d) for d in rig.sensor_dofs]
    exact = full.frf(w, ["A.w"])[:, sensors, 0]
    rows = np.eye(s.n)[sensors]
    reduced = model.physical_frf(w, np.eye(s.n)[a], rows)
    assert np.abs(reduced - exact).max() / np.abs(exact).max() < 1e-4
    assert model.n == 6 and K.shape[0] == 40
    # the check can fail: a cutoff below the second mode loses it
    coarse = parse_rig(rig.text.replace("mode_cutoff = 400.0", "mode_cutoff = 100.0"), "coarse.toml").linear
    worse = coarse.physical_frf(w, np.eye(s.n)[a], rows)
    assert np.abs(worse - exact).max() / np.abs(exact).max() > 1e-2


# --- nonlinear physics --------------------------------------------------------------
def test_duffing_peak_follows_the_backbone_and_sweeps_show_hysteresis():
    """Small amplitude (displacement THD below 1 %): the up-sweep peak sits on the backbone
    w^2 = w0^2 + 3 k3 X^2 / (4 m); the down sweep stays on the lower branch there."""
    k, k3, c, force = (TWO_PI * 5.0) ** 2, 2.0e5, 1.0, 1.0
    rig = sdof_rig(k, f'{{ law = "cubic", k3 = {k3!r} }}', damping=c, rate=256.0)
    lines = np.arange(5.0, 5.6, 0.01)

    def sweep(frequencies):
        sim = RigSimulator(rig)
        sim.set_output(True)
        out = []
        for f in frequencies:
            f, h = steady_harmonics(sim, f, force, settle=5.0, periods=5)
            # acceleration harmonics / (k w)^2: displacement THD
            displacement_thd = abs(h.amplitudes[3, 1]) / 9 / abs(h.fundamental[1])
            out.append((f, abs(h.fundamental[1]) / (TWO_PI * f) ** 2, displacement_thd))
        return np.array(out)

    up = sweep(lines)
    peak = np.argmax(up[:, 1])
    f_peak, X_peak, thd = up[peak]
    backbone = math.sqrt(k + 0.75 * k3 * X_peak**2) / TWO_PI
    assert thd < 0.01
    assert f_peak / 5.0 - 1 > 0.03                      # a clear hardening shift ...
    assert f_peak == pytest.approx(backbone, rel=0.01)  # ... that sits on the backbone
    down = sweep(lines[::-1])[::-1]
    assert up[peak, 1] > 1.5 * down[peak, 1]
    assert np.abs(up[:, 1] - down[:, 1]).max() > 0.5 * X_peak   # jumps: the branches differ


def coulomb_reference(m, k, fs, F0, w, periods, samples):
    """Exact response of m x'' + k x + fs sgn(x') = F0 sin(w t) from rest, with true stops.

    Piecewise analytic: while sliding in direction s the motion is the closed-form solution
    of m x'' + k x = F0 sin(w t) - s fs; velocity zeros and the end of a stop (when
    |F0 sin(w t) - k x| reaches fs) are located by bracketing and brentq.
    Returns x on ``samples`` points per period over the last two periods.
    """
    wn = math.sqrt(k / m)
    P = F0 / (k - m * w * w)
    T = TWO_PI / w
    t_end = periods * T
    scan = min(T, TWO_PI / wn) / 400

    def slide(t0, x0, v0, s, t):
        A = x0 - P * math.sin(w * t0) + s * fs / k
        B = (v0 - P * w * math.cos(w * t0)) / wn
        c, sn = math.cos(wn * (t - t0)), math.sin(wn * (t - t0))
        return A * c + B * sn + P * math.sin(w * t) - s * fs / k, -A * wn * sn + B * wn * c + P * w * math.cos(w * t)

    def drive(t, x):
        return F0 * math.sin(w * t) - k * x

    events = [(0.0, 0.0, 0.0, True, 0.0)]
    t, x, v, stuck, s = 0.0, 0.0, 0.0, True, 0.0
    while t < t_end:
        if stuck:
            x0 = x

            def excess(tt):
                return abs(drive(tt, x0)) - fs
            tt = t
            while excess(tt + scan) <= 0 and tt < t_end:
                tt += scan
            if tt >= t_end:
                break
            t = brentq(excess, tt, tt + scan, xtol=1e-14) if excess(tt) <= 0 else tt
            s, stuck, v = math.copysign(1.0, drive(t, x0)), False, 0.0
        else:
            t0, x0, v0 = t, x, v

            def forward(tt):
                return slide(t0, x0, v0, s, tt)[1] * s
            tt = t0 + 1e-12
            while forward(tt + scan) > 0 and tt < t_end:
                tt += scan
            if tt >= t_end:
                break
            t = brentq(forward, tt, tt + scan, xtol=1e-14)
            x, v = slide(t0, x0, v0, s, t)[0], 0.0
            if abs(drive(t, x)) <= fs:
                stuck = True
            else:
                s = math.copysign(1.0, drive(t, x))
        events.append((t, x, v, stuck, s))
    times = np.linspace(t_end - 2 * T, t_end, 2 * samples, endpoint=False)
    out = np.empty_like(times)
    j = 0
    for i, tt in enumerate(times):
        while j + 1 < len(events) and events[j + 1][0] <= tt:
            j += 1
        t0, x0, v0, st, s = events[j]
        out[i] = x0 if st else slide(t0, x0, v0, s, tt)[0]
    return out


def stiff_friction_reference(M, C, K, k3, fs, F0, f, ramp, times):
    """Exact response from rest of M x'' + C x' + K x + [k3 x1^3, fs sgn(x2')] = [0, F(t)], with true stops of x2.

    F(t) = F0 min(t / ramp, 1) sin(2 pi f t), the generator's linear ramp. Event driven: sliding phases in
    direction s and stops of x2 (x1 moving alone while the friction holds x2) are integrated by DOP853 to the
    events that end them (x2' reaching zero; the holding force reaching fs). Returns x1, x2 at ``times``.
    """
    Minv = np.linalg.inv(M)

    def force(t):
        return F0 * min(t / ramp, 1.0) * math.sin(TWO_PI * f * t)

    def holding(t, x1, x2):
        return force(t) - K[1, 0] * x1 - K[1, 1] * x2

    def sliding(t, y, s):
        load = -C @ y[2:] - K @ y[:2] - np.array([k3 * y[0] ** 3, s * fs - force(t)])
        return np.concatenate([y[2:], Minv @ load])

    def held(t, y, x2):
        return [y[1], -(C[0, 0] * y[1] + K[0, 0] * y[0] + K[0, 1] * x2 + k3 * y[0] ** 3) / M[0, 0]]

    def slips(t, y, x2):
        return abs(holding(t, y[0], x2)) - fs

    def stops(t, y, s):
        return y[3] * s

    slips.terminal = stops.terminal = True
    stops.direction = -1
    out = np.full((len(times), 2), np.nan)
    t, y, s, t_end = 0.0, np.zeros(4), 0.0, times[-1]
    options = dict(method="DOP853", rtol=1e-11, atol=1e-13, dense_output=True)
    while t < t_end:
        span = times >= t
        if s == 0.0:  # x2 held
            sol = solve_ivp(held, (t, t_end), y[[0, 2]], events=slips, args=(y[1],), **options)
            span &= times <= sol.t[-1]
            out[span] = np.column_stack([sol.sol(times[span])[0], np.full(span.sum(), y[1])])
            t, y = sol.t[-1], np.array([sol.y[0, -1], y[1], sol.y[1, -1], 0.0])
            s = math.copysign(1.0, holding(t, y[0], y[1]))
        else:
            sol = solve_ivp(sliding, (t, t_end), y, events=stops, args=(s,), **options)
            span &= times <= sol.t[-1]
            out[span] = sol.sol(times[span])[:2].T
            t, y = sol.t[-1], sol.y[:, -1].copy()
            y[3] = 0.0
            hold = holding(t, y[0], y[1])
            s = 0.0 if abs(hold) <= fs else math.copysign(1.0, hold)
    return out


def den_hartog_amplitude(m, k, fs, F0, w):
    """Den Hartog (1931): steady non-stop motion of the Coulomb oscillator under F0 sin(w t)."""
    beta = w / math.sqrt(k / m)
    V = 1.0 / (1.0 - beta**2)
    U = math.sin(math.pi / beta) / (beta * (1.0 + math.cos(math.pi / beta)))
    return F0 / k * math.sqrt(V**2 - (fs / F0 * U) ** 2)


@pytest.mark.parametrize("fs, f, stops", [(0.3, 0.7, False), (0.3, 1.4, False), (0.5, 0.9, False),
                                          (0.8, 0.5, True)])
def test_coulomb_true_stick_slip_matches_exact_references(fs, f, stops):
    m, k, F0 = 1.0, TWO_PI**2, 1.0
    w = TWO_PI * f
    rate = 512.0
    sim = RigSimulator(sdof_rig(k, f'{{ law = "coulomb", fs = {fs!r} }}', rate=rate))
    sim.set_sine(f, F0)
    sim.set_output(True)
    sim.advance(int(rate * 60 / f))
    sim.advance(int(round(2 * rate / f)))
    x = sim.truth.displacement("x")
    amplitude = (x.max() - x.min()) / 2
    reference = coulomb_reference(m, k, fs, F0, w, periods=60, samples=2000)
    assert amplitude == pytest.approx((reference.max() - reference.min()) / 2, rel=0.01)
    if stops:
        # the mass rests for part of each cycle, so Den Hartog's non-stop solution does not apply
        stopped = np.mean(np.abs(sim.truth.velocity("x")) < 1e-9)
        assert stopped > 0.1
        assert abs(amplitude / den_hartog_amplitude(m, k, fs, F0, w) - 1) > 0.1
    else:
        assert amplitude == pytest.approx(den_hartog_amplitude(m, k, fs, F0, w), rel=0.01)


@pytest.mark.parametrize("laws", ['{ law = "coulomb", fs = 0.4 }', '{ law = "jenkins", kt = 20.0, fs = 0.4 }',
                                  '{ law = "quadratic_damping", c2 = 0.8 }'])
def test_energy_balance_per_cycle(laws):
    """Steady state: the work of the force gauge per cycle equals what the damping dissipates."""
    c = 0.05
    sim = RigSimulator(sdof_rig(TWO_PI**2, laws, damping=c, rate=2048.0))
    sim.set_output(True)
    f, _ = steady_harmonics(sim, 0.9, 1.0, settle=60.0, periods=4)
    truth = sim.truth
    v = truth.velocity("x")
    dt = 1.0 / sim.sample_rate
    work_in = np.sum(truth.channels[:, 0] * v) * dt
    dissipated = np.sum(truth.element_force[:, 0] * v) * dt + np.sum(c * v * v) * dt
    assert work_in > 0
    assert dissipated == pytest.approx(work_in, rel=0.01)
    assert np.sum(truth.element_force[:, 0] * v) * dt > 0.2 * work_in  # the element does dissipate


def test_shaker_force_drops_at_resonance_as_the_frequency_domain_model_says():
    k, m, c = (TWO_PI * 20.0) ** 2, 1.0, 2.0
    R, L, Bl, ma, ks, cs = 4.0, 1e-3, 10.0, 0.05, 500.0, 0.5
    shaker = (f"[shaker]\nresistance = {R}\ninductance = {L}\nforce_factor = {Bl}\narmature_mass = {ma}\n"
              f"suspension_stiffness = {ks}\nsuspension_damping = {cs}\n")
    rig = sdof_rig(k, "", mass=m, damping=c, rate=1024.0, extra=shaker)
    forces = {}
    for f in (10.0, 19.9, 40.0):
        sim = RigSimulator(rig)
        sim.set_output(True)
        f, _ = steady_harmonics(sim, f, 1.0, settle=4.0)
        # gauge force per volt from the unfiltered truth (the filter delays every channel alike)
        force = harmonics(sim.truth.channels[:, 0], sim.sample_rate, f, 3).fundamental
        volts = harmonics(sim.truth.drive, sim.sample_rate, f, 3).fundamental
        w = TWO_PI * f
        receptance = 1.0 / (k - m * w**2 + 1j * w * c)
        armature = -ma * w**2 + 1j * w * cs + ks
        expected = Bl / ((R + 1j * w * L) * (1 + armature * receptance) + Bl**2 * 1j * w * receptance)
        assert force / volts == pytest.approx(expected, rel=1e-3)
        forces[f] = abs(force)
    low, resonance, high = forces.values()
    assert resonance < 0.25 * min(low, high)


@pytest.mark.slow
def test_paper_beam_softens_and_gains_damping_over_the_plan_force_range():
    rig = load_rig("paper-beam")
    peaks = []
    for voltage in (0.05, 3.0):   # gauge force about 0.02 N and 1.2 N at resonance: the plan's range
        sim = RigSimulator(rig)
        sim.set_output(True)
        lines = []
        for f in np.arange(51.6, 53.6, 0.1):
            f, h = steady_harmonics(sim, f, voltage, settle=3.0, periods=20, n_harmonics=2)
            lines.append((f, abs(h.fundamental[1] / h.fundamental[0]), abs(h.fundamental[0])))
        lines = np.array(lines)
        peak = lines[np.argmax(lines[:, 1])]
        peaks.append(peak)
    (f_low, a_low, force_low), (f_high, a_high, force_high) = peaks
    assert force_low < 0.03 and force_high > 1.0
    assert f_high < f_low - 0.3          # softening: the resonance moves down
    assert a_high < 0.6 * a_low          # damping grows: the accelerance peak drops


def _iwan_memory(sim, term):
    """The committed state of law term ``term`` (an iwan) from a simulator snapshot, and a reach
    (rad or m) beyond its present position and every remembered reversal point."""
    state = sim.state_snapshot().law_states[term, :LAWS["iwan"].n_state].copy()
    remembered = state[4:4 + 2 * int(state[0]):2]
    return state, 1.1 * max(np.max(np.abs(remembered), initial=0.0), abs(state[2]))


@pytest.mark.parametrize("chi, beta, amplitude", [(-0.9, 0.0, 0.01), (-0.5, 0.1, 0.3), (0.0, 0.0, 1.5)])
def test_iwan_through_slow_amplitude_ramps_overflowing_its_memory_does_not_diverge(chi, beta, amplitude):
    """A quasi-static Iwan element (its mode at 1.2 kHz, driven at 73 Hz) whose response decays
    over 100 cycles nests more reversals than the law remembers; growing again closes loops
    across the merged points. A force jump there leaves the step-end equation without a
    solution (the element is stiff enough for the step to feel it: D kt = -0.44), so this
    diverged while merging dropped loops without keeping the memory consistent. From deep
    micro-slip (X / phi_max below 1e-3 with chi = -0.9) to macro-slip (1.5 fs)."""
    values = {"kt": 5.5e4, "fs": 1.0, "chi": chi, "beta": beta}
    laws = "{ law = \"iwan\", " + ", ".join(f"{k} = {v!r}" for k, v in values.items()) + " }"
    rig = sdof_rig(1.0e3, laws, mass=1.0e-3, damping=0.75, rate=1024.0, extra="[generator]\nramp_cycles = 100")
    sim = RigSimulator(rig)
    sim.set_output(True)
    frequency, ramp = 73.0, int(1.3 * 100 / 73.0 * 1024)
    for level in (amplitude, 0.02 * amplitude, 1.1 * amplitude):
        sim.set_sine(frequency, level)
        sim.advance(ramp)
        state, reach = _iwan_memory(sim, 0)
        assert iwan_lipschitz_excess(state, values, reach) <= 1e-6


def test_paper_beam_random_drive_then_low_level_sine_steps():
    """The campaign's start on paper-beam: a random run piles up nested reversals in the Iwan
    contact, then sine steps at 0.02 N close loops across the merged ones. The contact's memory
    stays that of a real history (its force continuous), which the step-end solve relies on."""
    sim = RigSimulator("paper-beam", seed=0)
    sim.set_noise(0.02, (20.0, 200.0))
    sim.set_output(True)
    sim.advance(5 * 2048)
    sim.set_noise(0.0, (20.0, 200.0))
    for frequency in (52.0, 52.1, 52.2):
        sim.set_sine(frequency, 0.04)
        sim.advance(2048)
    values = dict(sim.rig.elements[1].laws[0].values)
    state, reach = _iwan_memory(sim, 0)  # the linear normal element is wholly in the linear part: no law state
    assert state[0] >= 32  # the memory is still well filled: many remembered points to cross
    assert iwan_lipschitz_excess(state, values, reach) <= 1e-6


def test_paper_2dof_below_the_stick_limit_stays_exactly_at_rest():
    """A 0.05 N sine on x2 against its 0.1 N Coulomb contact: x2 sticks from rest, so x1 is never
    loaded and the rig stays at rest. The free element's forces are then round-off; judged
    only against themselves they could never converge, and this diverged within 25 s."""
    sim = RigSimulator("paper-2dof")
    sim.set_sine(3.2, 0.05)
    sim.set_output(True)
    for _ in range(40):
        sim.advance(256)
        assert sim.element_states()["right"]["mode"] == "stick"
        assert np.max(np.abs(sim.truth.q)) <= 1e-12


# --- sensors, clock, generator ----------------------------------------------------
def test_clock_offset_shifts_the_apparent_frequency():
    rig = sdof_rig(TWO_PI**2 * 25, "", damping=1.0, rate=1024.0, extra="clock_offset_ppm = 250.0")
    sim = RigSimulator(rig)
    sim.set_sine(37.0, 1.0)
    sim.set_output(True)
    sim.advance(1024)
    fit = sine_fit(sim.advance(20480)[:, 0], sim.sample_rate, 37.0)
    assert fit.frequency == pytest.approx(37.0 / (1 + 250e-6), rel=2e-8)


def test_adc_clipping_counter_and_resolution():
    rig = sdof_rig(TWO_PI**2, "", damping=1.0, rate=256.0,
                   extra="force_range = 0.5\nresolution = 12")
    sim = RigSimulator(rig)
    sim.set_sine(1.0, 1.0)
    sim.set_output(True)
    block = sim.advance(2048)
    truth = sim.truth.channels[:, 0]
    assert sim.lsb[0] == pytest.approx(1.0 / 4096)
    np.testing.assert_allclose(block[:, 0] / sim.lsb[0], np.round(block[:, 0] / sim.lsb[0]), atol=1e-9)
    assert block[:, 0].max() <= 0.5 and block[:, 0].min() >= -0.5
    # the filter delays the channels: compare the counts with the delayed truth
    assert sim.clip_counts[0] == pytest.approx(np.sum(np.abs(truth) > 0.5), abs=2 * sim.filter_delay + 4)
    assert sim.clip_counts[0] > 100 and sim.clip_counts[1] == 0
    sim.reset_clip_counts()
    sim.set_sine(1.0, 0.3)
    sim.advance(2048)
    sim.advance(1024)
    assert sim.clip_counts[0] <= 2 * 256  # only the ramp-down transient may still clip


def test_noise_level_statistics():
    noisy = sdof_rig(TWO_PI**2 * 16, "", damping=1.0, rate=512.0, extra="[noise]\nforce = 0.02\nacceleration = 0.05")
    clean = sdof_rig(TWO_PI**2 * 16, "", damping=1.0, rate=512.0)
    blocks = []
    for rig in (noisy, clean):
        sim = RigSimulator(rig, seed=4)
        sim.set_sine(3.0, 1.0)
        sim.set_output(True)
        sim.advance(5120)
        blocks.append(sim.advance(8192))
    difference = blocks[0] - blocks[1]
    rms = np.sqrt(np.mean(blocks[1] ** 2, axis=0))
    np.testing.assert_allclose(np.std(difference, axis=0) / rms, [0.02, 0.05], rtol=0.05)
    assert abs(np.corrcoef(difference[:-1, 1], difference[1:, 1])[0, 1]) < 0.05  # white


def test_generator_phase_continuity_ramps_and_output_off():
    sim = RigSimulator(sdof_rig(TWO_PI**2 * 16, "", damping=1.0, rate=1024.0))
    sim.set_sine(5.0, 1.0)
    sim.set_output(True)
    sim.advance(1024)
    first = sim.truth.drive
    # the amplitude ramps over 3 cycles (0.6 s) from zero
    envelope_end = np.abs(first[:int(0.6 * 1024)]).max()
    assert envelope_end < 1.0 and np.abs(first[int(0.7 * 1024):]).max() == pytest.approx(1.0, abs=1e-3)
    sim.set_sine(7.0, 2.0)
    sim.advance(2048)
    drive = np.concatenate([first, sim.truth.drive])
    steps = np.abs(np.diff(drive))
    assert steps.max() < TWO_PI * 7.0 * 2.0 / 1024 * 1.05   # no jump: slope-limited everywhere
    sim.set_output(False)
    block = sim.advance(256)
    assert np.all(sim.truth.drive == 0.0)
    assert abs(block[-1, 0]) < 1e-6
    sim.set_output(True)
    sim.advance(64)
    assert np.abs(sim.truth.drive).max() < 2.0 * 64 / 1024 / (3 / 7.0) * 1.01  # ramps up again


def noise_run(seed):
    sim = RigSimulator(sdof_rig(TWO_PI**2 * 16, "", damping=1.0, rate=512.0), seed=seed)
    sim.set_noise(0.3, (10.0, 60.0))
    sim.set_output(True)
    sim.advance(512)
    return sim.advance(512 * 40), sim.truth.drive


def test_band_limited_noise_drive_level_band_and_seed():
    block, drive = noise_run(seed=2)
    assert np.std(drive) == pytest.approx(0.3, rel=0.05)
    spectrum = np.abs(np.fft.rfft(drive)) ** 2
    f = np.fft.rfftfreq(len(drive), 1 / 512.0)
    inside = spectrum[(f > 10) & (f < 60)].sum()
    assert spectrum[(f < 3) | (f > 150)].sum() < 1e-3 * inside
    np.testing.assert_array_equal(noise_run(seed=2)[0], block)
    assert not np.array_equal(noise_run(seed=3)[0], block)


def test_snapshot_restore_repeats_the_future_exactly():
    sim = RigSimulator(load_rig("paper-2dof"))
    sim.set_sine(1.3, 0.8)
    sim.set_output(True)
    sim.advance(1000)
    state = sim.state_snapshot()
    future = sim.advance(777)
    sim.set_sine(2.0, 0.1)
    sim.advance(100)
    sim.restore_state(state)
    sim.set_sine(1.3, 0.8)
    assert sim.time == pytest.approx(1000 / 256)
    np.testing.assert_array_equal(sim.advance(777), future)


def test_divergence_is_reported():
    sim = RigSimulator(sdof_rig(100.0, '{ law = "cubic", k3 = -1.0e4 }', damping=0.1, rate=256.0))
    sim.set_sine(1.0, 50.0)
    sim.set_output(True)
    with pytest.raises(SimulationError, match="diverged"):
        sim.advance(256 * 20)



def test_a_step_ending_on_the_jump_of_velocity_stiffness_crosses_it():
    """velocity_stiffness, (pi/2) gamma |x'| sgn(x), jumps by pi gamma |x'| where a moving element crosses
    x = 0. A step whose free motion ends within |D_x| pi gamma |x'| / 2 of the crossing (8e-7 m here) has no
    root of its step-end equation: the residual steps over zero (-1.27 to +1.27 N here), and the
    integration stopped ("the element forces have no solution"; the hidden-effect matrix case "2dof
    velocity stiffness" after 130 s). The step ends on the jump and the motion crosses it: the free
    vibration from there agrees with an independent integration restarted at every crossing."""
    import dataclasses

    gamma, x_dot = 4.0, -0.2
    sim = RigSimulator(sdof_rig(2000.0, f'{{ law = "velocity_stiffness", gamma = {gamma} }}', extra="oversample = 1"))
    c = 0.5 * math.pi * gamma
    law_force = c * abs(x_dot)  # x > 0 moving down
    steps = sim._on.steps
    free_end = [(steps.Cy @ (steps.Phi @ [x, x_dot] + steps.Pg0[:, 0] * law_force))[0] for x in (0.0, 1.0)]
    x_start = -free_end[0] / (free_end[1] - free_end[0])  # the free step ends on x = 0
    start = dataclasses.replace(sim.state_snapshot(), z=np.array([x_start, x_dot]), g=np.array([law_force]),
                                g_prev=np.full((3, 1), law_force))
    sim.restore_state(start)
    sim.advance(256)
    q = sim.truth.q[:, 0]

    def rhs(t, y):
        return [y[1], -2000.0 * y[0] - c * abs(y[1]) * np.sign(y[0] if y[0] != 0.0 else y[1])]

    def crossing(t, y):
        return y[0]
    crossing.terminal = True
    crossing.direction = -1.0  # then alternately up and down: a restart on x = 0 is no crossing
    t_out = sim.truth.time - sim.truth.time[0]
    t, y, reference = 0.0, [x_start, x_dot], []
    while t < t_out[-1]:
        sol = solve_ivp(rhs, (t, t_out[-1]), y, events=crossing, rtol=1e-11, atol=1e-14, dense_output=True,
                        first_step=1e-6)
        t_next = sol.t[-1] if sol.status == 1 else math.inf  # a crossing, or the end
        reference += [sol.sol(tk)[0] for tk in t_out[(t_out >= t) & (t_out < t_next)]]
        t, y = t_next, sol.y[:, -1]
        y[0] = 0.0
        crossing.direction = -crossing.direction
    amplitude = np.max(np.abs(reference))
    # 1.0 % measured: a step across a jump holds the law force first-order (one such step per crossing, 7 here,
    # at 512 steps per second); the step that ends on the jump adds nothing visible
    assert np.max(np.abs(q - reference)) < 2e-2 * amplitude, np.max(np.abs(q - reference)) / amplitude


# --- the paper's numerical example end to end --------------------------------------
@pytest.mark.slow
def test_paper_example_end_to_end():
    """Paper eqs. 22-24: stepped sine up at 0.8 N on paper-2dof, fundamental per line, closed-form
    identification, law fits: kn1, kn2, cn, mu within 1.5 %."""
    from analysis.fitting.fit import fit_laws
    from analysis.identification.identify import identify_complex_stiffness

    rig = load_rig("paper-2dof")
    fs = rig.daq.sample_rate
    sim = RigSimulator(rig)
    sim.set_output(True)
    lines, receptance, distortion = [], [], []
    for f in np.arange(0.8, 3.2 + 1e-9, 0.025):
        periods = max(4, math.ceil(4 * f))
        n = int(round(periods * fs / f))
        f = periods * fs / n                      # coherent line next to the plan's
        sim.set_sine(f, 0.8)
        previous = None
        for _ in range(40):                       # settle: until one block repeats the last
            h = harmonics(sim.advance(n), fs, f, 5)
            if previous is not None and np.abs(h.fundamental - previous).max() <= 1e-4 * np.abs(previous).max():
                break
            previous = h.fundamental
        w = TWO_PI * f
        lines.append(w)
        receptance.append(-h.fundamental[1:] / h.fundamental[0] / w**2)
        distortion.append(h.thd[1:].max())
    w, receptance, distortion = np.array(lines), np.array(receptance), np.array(distortion)
    result = identify_complex_stiffness(rig.structure, receptance, ["x1", "x2"], "x2", rig.elements,
                                        w=w, force=0.8)
    # describing functions describe a harmonic motion: leave out lines the contact turns into
    # stick-slip (THD above 10 %)
    use = ~result.ill_conditioned & (distortion < 0.1)
    assert use.sum() > 60
    left = fit_laws(["cubic", "quadratic_damping"], result.amplitude[use, 0], w[use], result.kbar[use, 0])
    right = fit_laws(["cubic", "coulomb"], result.amplitude[use, 1], w[use], result.kbar[use, 1])
    assert -left.terms[0].params["k3"] == pytest.approx(500.0, rel=0.015)
    assert left.terms[1].params["c2"] == pytest.approx(1.0, rel=0.015)
    assert -right.terms[0].params["k3"] == pytest.approx(750.0, rel=0.015)
    assert right.terms[1].params["fs"] == pytest.approx(0.1, rel=0.015)


@pytest.mark.parametrize("amplitude, stuck", [(3.0, False), (0.3, True)])
def test_stiff_friction_rig_matches_an_exact_stick_slip_reference(amplitude, stuck):
    """The speed benchmark's stiff rig (tests/rigs/stiff-friction.toml): at 3 N the cubic stiffens x1's spring
    about 6 x, at 0.3 N the friction holds x2 for part of every cycle. Over 10 s from rest (the generator's
    ramp included) the displacements stay within 1 % of the largest displacement of an event-driven
    reference, and a four times finer internal step comes at least 2.5 x closer (the error is the step's)."""
    text = (Path(__file__).parent / "rigs" / "stiff-friction.toml").read_text()
    f, seconds = 2.0, 10.0
    errors = []
    for oversample in (4, 16):
        rig = parse_rig(text + f"oversample = {oversample}\n", "stiff-friction.toml")
        sim = RigSimulator(rig)
        sim.set_sine(f, amplitude)
        sim.set_output(True)
        sim.advance(int(seconds * sim.sample_rate))
        truth = sim.truth
        x = np.column_stack([truth.displacement("x1"), truth.displacement("x2")])
        if oversample == 4:
            assert (np.mean(np.abs(truth.velocity("x2")) < 1e-9) > 0.01) == stuck
            s = rig.structure
            reference = stiff_friction_reference(s.M, s.C, s.K, 5.0e4, 0.03, amplitude, f,
                                                 rig.generator.ramp_cycles / f, truth.time)
        errors.append(np.abs(x - reference).max(axis=0) / np.abs(reference).max(axis=0))
    assert np.all(errors[0] < 0.01), errors
    assert np.all(errors[1] < errors[0] / 2.5), errors


def test_anti_alias_filter_streamed_in_chunks_equals_one_filtering_of_the_whole_record():
    """The polyphase filter, fed in chunks shorter and longer than its history, keeps every
    oversample-th output of scipy's direct filtering of the whole record (zero initial state)."""
    taps = _anti_alias_taps(256.0, 4, 0.4)
    record = np.random.default_rng(3).standard_normal((4 * 700, 3))
    history = np.zeros((len(taps) - 1, 3))
    chunks, start = [], 0
    for length in (4, 8, 40, 400, 1200, 4, 1144):
        chunks.append(kernels.fir_decimate(record[start:start + length], history, taps, 4))
        start += length
    assert start == len(record)
    expected = scipy.signal.lfilter(taps, [1.0], record, axis=0)[::4]
    np.testing.assert_allclose(np.concatenate(chunks), expected, rtol=0, atol=1e-13)


RIGS_DIR = Path(__file__).parent / "rigs"
# rig, sine (Hz, drive), seconds with the output on: every built-in and test rig, friction sticking on the stiff one
MODAL_CASES = [("paper-2dof", 1.27, 0.8, 3.0), ("paper-beam", 53.0, 1.0, 1.0),
               (RIGS_DIR / "stiff-friction.toml", 2.0, 0.3, 3.0), (RIGS_DIR / "hardening.toml", 9.5, 5.0, 2.0),
               (RIGS_DIR / "linear-shaker.toml", 12.0, 1.0, 2.0)]


def _modal_run(rig, f, drive, seconds, dense, monkeypatch):
    with monkeypatch.context() as m:
        m.setattr(simulator, "_MODAL_MIN_STATES", 0)  # the small rigs too
        if dense:
            m.setattr(simulator, "_MAX_MODAL_CONDITION", 0.0)  # no basis is this well conditioned
        sim = RigSimulator(rig)
    sim.set_sine(f, drive)
    sim.set_output(True)
    sim.advance(int(seconds * sim.sample_rate))
    truths = [sim.truth]
    modes = [m["mode"] for m in sim.element_states().values()]
    sim.set_output(False)  # the amplifier-off matrices of a shaker rig, entered mid-motion
    sim.advance(int(0.25 * sim.sample_rate))
    truths.append(sim.truth)
    return sim, truths, modes, sim.state_snapshot()


@pytest.mark.parametrize("rig, f, drive, seconds", MODAL_CASES, ids=lambda c: Path(str(c)).stem)
def test_modal_step_equals_the_dense_step_to_round_off(rig, f, drive, seconds, monkeypatch):
    """The block-diagonal step in the rig's real modal basis and the dense step in physical coordinates
    give the same truth, channels and state: the change of coordinates only reorders round-off."""
    modal, truths, modes, state = _modal_run(rig, f, drive, seconds, False, monkeypatch)
    dense, dense_truths, dense_modes, dense_state = _modal_run(rig, f, drive, seconds, True, monkeypatch)
    several_modes = modal.model.n > 1  # one mode is one block: the dense step itself
    assert not dense._on.modal and modal._on.modal == several_modes and modal._off.modal == several_modes
    assert modes == dense_modes
    for truth, reference in zip(truths, dense_truths):
        for name in ("q", "qdot", "element_force", "channels"):
            a, b = getattr(truth, name), getattr(reference, name)
            difference = np.abs(a - b).max(initial=0.0) / np.abs(b).max(initial=1e-300)
            assert difference < 1e-8, (name, difference)
    np.testing.assert_allclose(state.z, dense_state.z, rtol=0, atol=1e-8 * np.abs(dense_state.z).max())
    np.testing.assert_array_equal(state.mode, dense_state.mode)


def test_a_defective_linear_part_keeps_the_dense_step(monkeypatch):
    """A critically damped mode (a double pole with one eigenvector) has no modal basis: the step stays
    dense, and the underdamped rig next to it takes the modal one."""
    def rig(c1):
        return parse_rig(f"""name = "critical"
[structure]
type = "lumped"
dofs = ["x1", "x2"]
mass = [[1.0, 0.0], [0.0, 1.0]]
stiffness = [[100.0, 0.0], [0.0, 400.0]]
damping = [[{c1}, 0.0], [0.0, 0.4]]
[excitation]
dof = "x1"
[sensors]
dofs = ["x1", "x2"]
[daq]
sample_rate = 256.0
""", "critical.toml")
    assert not RigSimulator(rig(2.0))._on.modal    # 4 states: the dense step is cheaper
    monkeypatch.setattr(simulator, "_MODAL_MIN_STATES", 0)
    assert not RigSimulator(rig(20.0))._on.modal   # c = 2 sqrt(k m)
    assert RigSimulator(rig(2.0))._on.modal


def test_an_element_without_laws_stays_out_of_the_solve_and_reports_zero_force():
    """The hidden-effect rigs carry elements the analysis model names but the rig leaves empty: such an
    element changes nothing (the same motion as the rig without it), has zero force and is free."""
    structure = """[structure]
type = "lumped"
dofs = ["x1", "x2"]
mass = [[1.0, 0.0], [0.0, 1.0]]
stiffness = [[3000.0, -1000.0], [-1000.0, 2000.0]]
rayleigh = [0.3, 1.0e-4]
[[element]]
name = "a"
dof = "x1"
laws = [ { law = "coulomb", fs = 0.08 }, { law = "cubic", k3 = 2.0e5 } ]
"""
    io = '[excitation]\ndof = "x2"\n[sensors]\ndofs = ["x1", "x2"]\n[daq]\nsample_rate = 512.0\n'
    idle = '[[element]]\nname = "b"\ndof = "x2"\nlaws = []\n'
    runs = []
    for text in (structure + io, structure + idle + io):
        sim = RigSimulator(parse_rig('name = "idle"\n' + text, "idle.toml"))
        sim.set_sine(6.0, 3.0)
        sim.set_output(True)
        sim.advance(1024)
        runs.append((sim.truth, sim.element_states(), sim.displacements()["x2"]))
    (alone, alone_states, _), (with_idle, states, x2) = runs
    np.testing.assert_allclose(with_idle.q, alone.q, rtol=0, atol=1e-12 * np.abs(alone.q).max())
    np.testing.assert_allclose(with_idle.element_force[:, 0], alone.element_force[:, 0], rtol=0,
                               atol=1e-12 * np.abs(alone.element_force).max())
    assert with_idle.element_force.shape[1] == 2 and not np.any(with_idle.element_force[:, 1])
    assert states["b"]["mode"] == "free" and states["a"]["mode"] == alone_states["a"]["mode"]
    assert states["b"]["displacement"] == pytest.approx(x2, rel=1e-12)


def test_a_spring_and_damper_element_stays_out_of_the_solve_and_reports_its_force():
    """A linear element is wholly in the linear part: the rig moves as the same rig with the spring and damper
    written into its structure matrices, and the element's force is k x + c x' of its own motion."""
    k, c = 700.0, 0.9

    def rig(stiffness, damping, element):
        return parse_rig(f"""name = "spring"
[structure]
type = "lumped"
dofs = ["x1", "x2"]
mass = [[1.0, 0.0], [0.0, 1.0]]
stiffness = {stiffness}
damping = {damping}
[[element]]
name = "a"
dof = "x1"
laws = [ {{ law = "cubic", k3 = 2.0e5 }} ]
{element}[excitation]
dof = "x2"
[sensors]
dofs = ["x1", "x2"]
[daq]
sample_rate = 512.0
""", "spring.toml")

    spring = f'[[element]]\nname = "b"\ndof = "x2"\nlaws = [ {{ law = "linear", k = {k}, c = {c} }} ]\n'
    runs = []
    for text in (rig([[3000.0, -1000.0], [-1000.0, 2000.0]], [[0.6, -0.1], [-0.1, 0.4]], spring),
                 rig([[3000.0, -1000.0], [-1000.0, 2000.0 + k]], [[0.6, -0.1], [-0.1, 0.4 + c]], "")):
        sim = RigSimulator(text)
        sim.set_sine(6.0, 3.0)
        sim.set_output(True)
        sim.advance(1024)
        runs.append((sim, sim.truth))
    (with_spring, truth), (_, reference) = runs
    assert len(with_spring.state_snapshot().g) == 1  # only the cubic is solved for
    np.testing.assert_allclose(truth.q, reference.q, rtol=0, atol=1e-10 * np.abs(reference.q).max())
    np.testing.assert_allclose(truth.element_force[:, 0], reference.element_force[:, 0], rtol=0,
                               atol=1e-10 * np.abs(reference.element_force[:, 0]).max())
    x2, v2 = truth.displacement("x2"), truth.velocity("x2")
    np.testing.assert_allclose(truth.element_force[:, 1], k * x2 + c * v2, rtol=0,
                               atol=1e-12 * np.abs(k * x2 + c * v2).max())


def _ramped_sine(n, spacing, phase, omega, level, target, rate):
    offset = omega * spacing * np.arange(_SINE_ROW)
    return kernels.ramped_sine(n, spacing, phase, omega, np.cos(offset), np.sin(offset), level, target, rate)


@pytest.mark.parametrize("n", [1, 2, 127, 128, 129, 300, 2049, 2 * 8192 + 1])
@pytest.mark.parametrize("phase", [0.0, 2.5, 6.2])
def test_the_drive_sine_equals_numpys_to_round_off(n, phase):
    """The generator's sine by angle addition over rows is np.sin of the same arguments to a few units in the last
    place of the largest argument."""
    omega, spacing = 2 * np.pi * 53.0, 0.5 / 8192
    argument = phase + omega * np.arange(n) * spacing
    difference = np.abs(_ramped_sine(n, spacing, phase, omega, 1.0, 1.0, 0.0) - np.sin(argument)).max()
    assert difference <= 4 * np.spacing(np.abs(argument).max())


@pytest.mark.parametrize("level, target", [(0.0, 2.0), (2.0, 0.5), (1.5, 1.5)])
def test_the_drive_amplitude_ramps_linearly_to_its_target_and_stays(level, target):
    """Rising, falling and held amplitudes: the sine times ``level +- rate tau``, clipped at the target."""
    omega, spacing, rate, n = 2 * np.pi * 7.0, 1 / 2048, 3.0, 2 * 2048 + 1
    tau = np.arange(n) * spacing
    amplitude = (np.minimum(level + rate * tau, target) if target > level else
                 np.maximum(level - rate * tau, target))
    expected = amplitude * np.sin(1.0 + omega * tau)
    np.testing.assert_allclose(_ramped_sine(n, spacing, 1.0, omega, level, target, rate), expected, rtol=0,
                               atol=1e-13)
