"""Numbers in the words a user reads: engineering notation, and a change printed with the digits it needs.

A value printed to three digits hides a change smaller than its last digit: "falls from -9.6e+06 to -9.6e+06
N/m" says nothing. :func:`change_words` names such a change as the change itself, "near -9.601e6 N/m, falling by
2.9 kN/m" (docs/workbench.md, "Numbers in the text").
"""
from __future__ import annotations

import math

_PREFIXES = {-15: "f", -12: "p", -9: "n", -6: "µ", -3: "m", 0: "", 3: "k", 6: "M", 9: "G", 12: "T"}
_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")
# a change of at least this fraction of the values shows in three digits as the values themselves
VISIBLE_CHANGE = 0.05


def _exponent(value: float) -> int:
    return int(math.floor(math.log10(abs(value)) + 1e-9))


def engineering(value: float, unit: str = "", digits: int = 3) -> str:
    """``value`` in engineering notation: a mantissa in [1, 1000) to ``digits`` significant digits and an SI
    prefix on ``unit`` ("20 µm", "1.5 kN/m"). Without a unit, plain numbers from 0.001 to 1000 and powers of ten
    beyond ("10⁻⁶")."""
    if value == 0 or not math.isfinite(value):
        return f"{value:g} {unit}".strip()
    exponent = _exponent(value)
    if not unit:
        if -3 <= exponent < 4:
            return f"{value:.{max(digits, 4)}g}"
        mantissa = value / 10.0**exponent
        head = "" if math.isclose(mantissa, 1.0) else f"{_rounded(mantissa, digits)}·"
        return f"{head}10{str(exponent).translate(_SUPERSCRIPT)}"
    third = min(max(3 * (exponent // 3), min(_PREFIXES)), max(_PREFIXES))
    return f"{_rounded(value / 10.0**third, digits)} {_PREFIXES[third]}{unit}"


def _rounded(mantissa: float, digits: int) -> str:
    """A mantissa in [1, 1000) to ``digits`` significant digits, never in exponent form ("100", not "1e+02")."""
    return f"{round(mantissa, max(digits - 1 - _exponent(mantissa), 0)):g}"


def significant(value: float, digits: int = 3) -> str:
    """``value`` to ``digits`` significant digits, with a short exponent beyond 0.001..10^4 ("-9.601e6")."""
    if value == 0 or not math.isfinite(value):
        return f"{value:g}"
    exponent = _exponent(value)
    if -3 <= exponent < 4:
        return f"{value:.{max(digits - 1 - exponent, 0)}f}" if exponent < digits - 1 else f"{value:.0f}"
    return f"{value / 10.0**exponent:.{digits - 1}f}e{exponent}"


def change_words(start: float, end: float, unit: str) -> tuple[str, str]:
    """How a quantity goes from ``start`` to ``end``, as (verb, rest): ("falls", "from 95.9 to 73.1 N·m/rad")
    where three digits show the change, else ("stays", "near -9.601e6 N/m, falling by 2.9 kN/m") with the value
    to the digits the change needs and the change itself."""
    change = end - start
    verb = "rises" if change > 0 else "falls"
    scale = max(abs(start), abs(end))
    if change == 0 or scale == 0 or abs(change) >= VISIBLE_CHANGE * scale:
        return verb, f"from {significant(start)} to {significant(end)} {unit}"
    digits = max(3, math.ceil(math.log10(scale / abs(change))))
    return "stays", (f"near {significant(start, digits)} {unit}, {'rising' if change > 0 else 'falling'} by "
                     f"{engineering(abs(change), unit, 2)}")


def parameter_words(name: str, value: float, stderr: float | None = None, undetermined: bool = False,
                    unit: str = "", digits: int = 5) -> str:
    """A fitted parameter as the user reads it: ``k3 = -742.1 ± 3.2 N/m^3``; ``beta: not determined by the data``,
    without a value, where the data do not determine it (its value is where the fit left it: a stiffness of 1e32
    that nothing bounds, one of two springs of which only the sum is known) -- the combinations the data do
    determine are printed apart. ``stderr`` None or not finite: the value alone."""
    if undetermined or (stderr is not None and not math.isfinite(stderr)):
        return f"{name}: not determined by the data"
    spread = "" if stderr is None else f" ± {stderr:.2g}"
    unit = "" if unit == "1" else unit          # "1": dimensionless
    return f"{name} = {value:.{digits}g}{spread} {unit}".rstrip()
