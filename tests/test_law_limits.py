"""The limits a fitted law can sit in over the amplitudes measured (Law.reading, docs/laws.md "Limits").

Truth: each law's own describing function (checked against quadrature in tests/test_laws.py) against the
limit's closed form written here: micro-slip kbar = kt - r(chi) (nu/pi) X^(chi+1) + j (nu/pi) X^(chi+1) with
r(chi) = 2 B(chi + 5/2, 3/2) (chi + 2)(chi + 3) / (chi + 1), read as the dissipation per cycle at the largest
amplitude, D = pi X_max^2 Im kbar(X_max) = nu X_max^(chi+3); Coulomb kbar = 4 j fs / (pi X)."""
import numpy as np
import pytest
from scipy.special import beta as beta_function

from analysis.laws import LAWS
from analysis.laws.base import Origin


@pytest.mark.parametrize("chi, beta", [(-0.5, 0.1), (0.0, 0.0), (0.6, 2.0)])
def test_an_iwan_element_that_never_slips_through_reads_as_micro_slip_with_its_dissipation_law(chi, beta):
    iwan = LAWS["iwan"]
    values = {"kt": 2.0e5, "fs": 40.0, "chi": chi, "beta": beta}
    X = np.geomspace(1e-7, 5e-5, 30)
    reading = iwan.reading(values, X.min(), X.max())
    assert reading.limit == "micro-slip" and reading.undetermined == ("fs", "beta")
    kt, D = reading.values["kt"], reading.values["D"]
    nu = reading.values["nu"]
    assert D == pytest.approx(nu * X.max() ** (chi + 3))
    r = 2 * beta_function(chi + 2.5, 1.5) * (chi + 2) * (chi + 3) / (chi + 1)
    law = iwan.describing_function(X, np.full_like(X, 100.0), **values)
    power = nu / np.pi * X ** (chi + 1)
    assert law.imag == pytest.approx(power, rel=1e-9)
    assert law.real == pytest.approx(kt - r * power, rel=1e-9)
    # beyond the slip range it is an Iwan element again
    assert iwan.reading(values, X.min(), 1.0) is None
    # measured from the reference (docs/laws.md, "Measured from the reference") the stiffness drops out as well:
    # the same chi and D, and kbar - kt their closed form alone
    relative = iwan.relative().reading(values, X.min(), X.max())
    assert relative.limit == "micro-slip" and relative.undetermined == ("kt", "fs", "beta")
    assert relative.values == {"chi": chi, "nu": pytest.approx(nu), "D": D}
    shifted = iwan.relative().describing_function(X, np.full_like(X, 100.0), **values)
    assert shifted.imag == pytest.approx(power, rel=1e-9)
    assert shifted.real == pytest.approx(-r * power, rel=1e-9)


@pytest.mark.parametrize("name, values", [("iwan", {"kt": 1e12, "fs": 2.0, "chi": 0.3, "beta": 1.0}),
                                          ("jenkins", {"kt": 1e12, "fs": 2.0})])
def test_a_slip_range_far_below_every_amplitude_reads_as_coulomb_friction(name, values):
    law = LAWS[name]
    X = np.geomspace(1e-5, 1e-3, 20)
    reading = law.reading(values, X.min(), X.max())
    assert reading.limit == "Coulomb friction" and reading.values == {"fs": 2.0} and "kt" in reading.undetermined
    kbar = law.describing_function(X, np.full_like(X, 100.0), **values)
    coulomb = 4 * reading.values["fs"] / (np.pi * X)
    assert kbar.imag == pytest.approx(coulomb, rel=0.05)
    assert np.all(np.abs(kbar.real) < 0.1 * coulomb)


@pytest.mark.parametrize("name, shape, saturation, within", [("tanh_softening", np.tanh, 1.0, 0.005),
                                                              ("arctan_softening", np.arctan, np.pi / 2, 0.1)])
def test_a_spring_that_saturates_a_decade_below_every_amplitude_reads_as_its_saturated_force(name, shape, saturation,
                                                                                             within):
    """alpha s(beta x) with 1 / beta a tenth of the smallest amplitude or less: kbar is the saturated force's,
    4 F / (pi X) with F = alpha at tanh's saturation and (pi/2) alpha at arctan's, within 0.4 % and 10 % at
    the decade; every larger beta reads the same, and beta is not determined. The law's kbar against quadrature
    of its force over a cycle."""
    law = LAWS[name]
    X = np.geomspace(1e-5, 1e-3, 12)
    t = (np.arange(40000) + 0.5) * (2.0 * np.pi / 40000)
    for beta in (10.0 / X.min(), 1e18):
        values = {"alpha": 2.0, "beta": beta}
        reading = law.reading(values, X.min(), X.max())
        assert reading.limit == "saturated spring" and reading.values == {"alpha": 2.0}
        assert reading.undetermined == ("beta",)
        kbar = law.describing_function(X, np.full_like(X, 100.0), **values)
        quadrature = [2.0 * np.mean(2.0 * shape(beta * x * np.sin(t)) * np.sin(t)) / x for x in X]
        assert kbar.real == pytest.approx(quadrature, rel=1e-4) and np.all(kbar.imag == 0.0)
        assert kbar.real == pytest.approx(4 * saturation * reading.values["alpha"] / (np.pi * X), rel=within)
    # a softening displacement above a tenth of the smallest amplitude: the law itself
    assert law.reading({"alpha": 2.0, "beta": 9.9 / X.min()}, X.min(), X.max()) is None


def test_a_law_inside_its_range_and_laws_without_limits_read_as_themselves():
    X_min, X_max = 1e-5, 1e-3
    assert LAWS["jenkins"].reading({"kt": 1e5, "fs": 10.0}, X_min, X_max) is None          # slips at 1e-4
    assert LAWS["iwan"].reading({"kt": 1e5, "fs": 10.0, "chi": -0.5, "beta": 0.1}, X_min, X_max) is None
    assert LAWS["cubic"].reading({"k3": 1e9}, X_min, X_max) is None


def test_an_iwan_element_whose_spike_carries_the_stiffness_reads_as_the_jenkins_element_of_its_spike():
    iwan, jenkins = LAWS["iwan"], LAWS["jenkins"]
    values = {"kt": 1.2e5, "fs": 36.7, "chi": 0.98, "beta": 5.5e28}
    X = np.geomspace(1e-5, 1e-3, 25)                  # stuck below 0.31 mm, slipping beyond
    reading = iwan.reading(values, X.min(), X.max())
    assert reading.limit == "Jenkins element" and reading.undetermined == ("chi", "beta")
    w = np.full_like(X, 500.0)
    as_iwan = iwan.describing_function(X, w, **values)
    as_jenkins = jenkins.describing_function(X, w, **reading.values)
    assert as_jenkins == pytest.approx(as_iwan, rel=1e-6, abs=1e-9 * values["kt"])


@pytest.mark.parametrize("chi", [-0.4, 0.13, 0.9])
def test_measured_from_the_reference_a_stuck_spike_of_any_size_leaves_the_continuum_s_micro_slip(chi):
    """Measured from the reference a stuck spike adds nothing to kbar - kt, however stiff: a fit can run kt and
    beta off together and keep the continuum's kt / (1 + beta) finite. What the data determine is then the
    continuum's micro-slip (chi, D), not a Jenkins element of the spike's 6e13 N/m."""
    iwan = LAWS["iwan"].relative()
    continuum, phi_max = 3.0e4, 2.0e-3                 # the continuum's stiffness kt / (1 + beta), its slip range
    beta = 2.0e9                                      # kbar - kt then holds kt's rounding, 6e13 * 1e-16 N/m
    kt = continuum * (1.0 + beta)
    # phi_max = fs/kt (chi + 2)(1 + beta)/(chi + 1 + beta (chi + 2)) (analysis/laws/iwan.py slip_range)
    fs = phi_max * kt * (chi + 1.0 + beta * (chi + 2.0)) / ((chi + 2.0) * (1.0 + beta))
    values = {"kt": kt, "fs": fs, "chi": chi, "beta": beta}
    X = np.geomspace(2e-6, 2e-4, 25)                  # every slider stuck beyond 2 mm: nothing slips through
    reading = iwan.reading(values, X.min(), X.max())
    assert reading.limit == "micro-slip" and reading.undetermined == ("kt", "fs", "beta")
    assert "e+13" not in reading.values_text() and set(reading.values) == {"chi", "nu", "D"}
    nu = reading.values["nu"]
    assert reading.values["D"] == pytest.approx(nu * X.max() ** (chi + 3))
    r = 2 * beta_function(chi + 2.5, 1.5) * (chi + 2) * (chi + 3) / (chi + 1)
    # the closed form against the law's own describing function, the continuum alone carrying its departure
    shifted = iwan.describing_function(X, np.full_like(X, 100.0), **values)
    power = nu / np.pi * X ** (chi + 1)
    assert shifted.imag == pytest.approx(power, rel=1e-6)
    assert shifted.real == pytest.approx(-r * power, rel=1e-6, abs=8 * np.finfo(float).eps * kt)   # kt - kt
    # the same element not measured from the reference holds kt itself: there the spike's stiffness is seen
    # and the continuum is a 1/(1 + beta) share of it, the spike's Jenkins element
    assert LAWS["iwan"].reading(values, X.min(), X.max()).limit == "Jenkins element"


def test_an_iwan_element_whose_spike_always_slips_reads_as_coulomb_friction_and_shows_no_stiffness():
    """A spike stiffer than anything measured, slipping at a force far below the smallest amplitude's: Coulomb
    friction, fs alone; the stiffness the fit left at 1e32 is not a finding and is not shown."""
    iwan, coulomb = LAWS["iwan"], LAWS["coulomb"]
    values = {"kt": 1.67e32, "fs": 0.0129, "chi": 0.9999, "beta": 9.7e28}
    X = np.geomspace(1.1e-5, 3.2e-4, 25)
    reading = iwan.reading(values, X.min(), X.max())
    assert reading.limit == "Coulomb friction" and set(reading.values) == {"fs"}
    assert reading.undetermined == ("kt", "chi", "beta") and "e+32" not in reading.values_text()
    w = np.full_like(X, 500.0)
    as_iwan = iwan.describing_function(X, w, **values)
    as_coulomb = coulomb.describing_function(X, w, **{"fs": reading.values["fs"]})
    assert as_coulomb.imag == pytest.approx(as_iwan.imag, rel=0.03)


def test_the_json_of_a_law_read_in_a_limit_gives_what_the_limit_leaves_open_as_null():
    """A Jenkins element whose slider slips at every amplitude measured is Coulomb friction: fs is a finding, kt
    (any stiffness beyond the structure's) is not, and the JSON says so as the text does (docs/contracts.md)."""
    from analysis.loop.workbench import ElementReport
    from analysis.mechanics.elements import Element, LawTerm
    from analysis.missing.diagnosis import ElementSamples

    X = np.geomspace(1e-3, 1e-2, 12)
    values = {"kt": 3.2e18, "fs": 2.0}
    kbar = LAWS["jenkins"].describing_function(X, np.full_like(X, 100.0), **values)
    samples = ElementSamples("joint", X, np.full_like(X, 100.0), kbar, np.full(X.size, 1e-3), np.ones(X.size))
    joint = Element("joint", ("x1",), [LawTerm(LAWS["jenkins"], dict(values))])
    (entry,) = ElementReport("joint", samples, None, X.size, 0).to_json(joint)["laws"]
    assert entry["reading"]["limit"] == "Coulomb friction" and entry["reading"]["undetermined"] == ["kt"]
    assert entry["params"] == {"kt": None, "fs": 2.0} and entry["undetermined"] == ["kt"]
    assert joint.laws[0].values["kt"] == 3.2e18          # the model keeps it: the prediction runs the law itself


def test_the_micro_slip_form_measured_from_an_origin_is_the_iwans_less_its_kbar_there():
    """The micro-slip form a fit takes for an Iwan element measured from an origin (docs/laws.md, "Measured from
    the reference") is, at the values it places back in the Iwan, that Iwan measured from the same origin: its
    closed-form departure less the spring and damper of the departure at the origin, nothing at the origin."""
    origin = Origin(2e-6, 2 * np.pi * 80.0)
    X_max = 5e-5
    X = np.geomspace(1e-7, X_max, 30)
    w = np.full_like(X, 2 * np.pi * 81.0)
    iwan = LAWS["iwan"].relative(origin)
    (form,) = iwan.limit_forms(X_max)
    assert form.from_reference and form.origin == origin and form.relative(origin) is form
    values = {"chi": -0.3, "D": 3e-4}
    placed = form.law_values(values)
    np.testing.assert_allclose(form.describing_function(X, w, **values),
                               iwan.describing_function(X, w, **placed), rtol=1e-9, atol=1e-9 * abs(
                                   complex(LAWS["iwan"].relative().describing_function(X_max, w[0], **placed))))
    assert abs(complex(form.describing_function(origin.X, origin.w, **values))) < 1e-12 * abs(
        complex(form.describing_function(X_max, origin.w, **values)))
