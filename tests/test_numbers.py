"""Numbers in the text: a change is printed with the digits it needs."""
import pytest

from analysis.missing.diagnosis import signature_words
from analysis.common.wording import change_words, engineering, significant


@pytest.mark.parametrize("value, digits, text", [
    (95.94, 3, "95.9"), (0.4781, 3, "0.478"), (-9.601e6, 4, "-9.601e6"), (1.5e-5, 3, "1.50e-5"), (6.2, 3, "6.20")])
def test_significant_digits_with_a_short_exponent(value, digits, text):
    assert significant(value, digits) == text


def test_a_change_below_the_printed_precision_is_named_as_the_change():
    # the normal element of the demo: -9.6009e6 -> -9.6038e6 read "falls from -9.6e+06 to -9.6e+06"
    verb, rest = change_words(-9.6009e6, -9.6038e6, "N/m")
    assert (verb, rest) == ("stays", "near -9.601e6 N/m, falling by 2.9 kN/m")


def test_a_visible_change_is_from_to():
    assert change_words(95.9, 73.1, "N·m/rad") == ("falls", "from 95.9 to 73.1 N·m/rad")
    assert change_words(0.478, 6.2, "N/m") == ("rises", "from 0.478 to 6.20 N/m")


def test_engineering_never_falls_back_to_an_exponent():
    assert engineering(100.0, "N/m", 2) == "100 N/m"
    assert engineering(2.94e3, "N/m", 2) == "2.9 kN/m"


def test_the_signature_sentence_names_a_small_change_itself():
    class Sig:      # the fields signature_words reads, as the demo's normal element gives them
        re_change_sigma, im_change_sigma = -4.0, 0.5
        re_small, re_large, im_small, im_large = -9.6009e6, -9.6038e6, -3.3e4, -3.3e4
        re_slope_X, im_slope_X, im_slope_w = -1e-4, 0.0, None
        mean_re, mean_im = -9.601e6, -3.3e4
    words = signature_words(Sig(), "N/m")
    assert words.re == "Re kbar stays near -9.601e6 N/m, falling by 2.9 kN/m (4 sigma)"
