"""A clone of the repository alone passes its tests: no test reaches outside the repository except through
tests/realdata.py, whose data that cannot ship are behind a skip with its reason; what the suite reads ships in
tests/data/ and is listed with its licence in THIRD-PARTY.md."""
import re
from pathlib import Path

import pytest

from realdata import BRB_MISSING, DATA, REALDATA, ROOT, UFF

# a path leaving the checkout: a parent of the repository, '..' in a literal, an absolute folder of a machine
OUTSIDE = re.compile(r"parents\[[2-9]\]|ROOT\.parent|\.parent\.parent\.parent|[\"']\.\./|[\"']/(?:work|home|root|mnt)/"
                     r"|[\"']shared[\"']|\bCONTACTID_REALDATA\b")
ALLOWED = {"realdata.py", "test_fresh_clone.py"}


NOT_A_PATH = "# not a path:"     # a line whose '../' is data (a hostile DOF name), said so with the reason


def reaches_outside(source: str) -> list[str]:
    """The lines of a test module that name a path outside the repository."""
    return [line.strip() for line in source.splitlines() if OUTSIDE.search(line) and NOT_A_PATH not in line]


def skips_without(source: str) -> bool:
    """A module using data from outside (REALDATA, BRB_MAT) skips when they are missing."""
    uses = re.search(r"\b(REALDATA|BRB_MAT)\b", source) is not None
    return not uses or ("skipif" in source and "BRB_MISSING" in source)


def test_the_rule_bites():
    assert reaches_outside('MAT = Path(__file__).resolve().parents[2] / "shared" / "x.mat"')
    assert reaches_outside('open("../shared/realdata/uff/a.uff")')
    assert reaches_outside("DATA = ROOT.parent / 'data'")
    assert not reaches_outside('DATA = ROOT / "tests" / "data" / "uff"')
    assert not reaches_outside('dofs = ["x1", "../x2"]   # not a path: a DOF name the import must refuse')
    assert reaches_outside('open("../x2")   # not a path')
    assert not skips_without("from realdata import BRB_MAT\nread(BRB_MAT)\n")
    assert skips_without("from realdata import BRB_MAT, BRB_MISSING\n"
                         "pytestmark = pytest.mark.skipif(not BRB_MAT.exists(), reason=BRB_MISSING)\n")


@pytest.mark.parametrize("module", sorted(str(p.relative_to(ROOT)) for p in (ROOT / "tests").rglob("*.py")
                                          if p.name not in ALLOWED))
def test_no_test_reads_outside_the_repository(module):
    source = (ROOT / module).read_text()
    assert reaches_outside(source) == [], f"{module} names a path outside the repository: use tests/realdata.py"
    assert skips_without(source), f"{module} reads data that cannot ship without a skip naming BRB_MISSING"


def test_the_shipped_data_lie_inside_and_are_listed_with_their_licence():
    assert DATA.is_relative_to(ROOT) and UFF.is_dir()
    notice = (ROOT / "THIRD-PARTY.md").read_text()
    for path in sorted(UFF.iterdir()):
        if path.suffix in (".uff", ".txt"):
            assert path.name in notice, f"{path.name} is not listed in THIRD-PARTY.md"
    assert "MIT" in (ROOT / "LICENSE").read_text()
    size = sum(p.stat().st_size for p in DATA.rglob("*") if p.is_file())
    assert size < 5e6, f"tests/data holds {size / 1e6:.1f} MB"


def test_the_reason_for_the_beam_names_where_to_get_it():
    assert "\n" not in BRB_MISSING and "mattiacenedese/BRBtesting" in BRB_MISSING
    assert str(REALDATA) in BRB_MISSING and "CONTACTID_REALDATA" in BRB_MISSING
