"""Where the tests find data that come from outside the repository.

Data the project may ship lie in tests/data/ (THIRD-PARTY.md lists them with their licences). Data it may not
ship, the Brake-Reuss beam's measurements (GPL-3.0), are looked for in the folder the environment variable
``CONTACTID_REALDATA`` names, by default ``../shared/realdata`` beside the checkout; a test of them skips with a
one-line reason saying where to get them (docs/import.md). This is the only test module that may name a path
outside the repository (tests/test_fresh_clone.py checks it).
"""
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
UFF = DATA / "uff"
REALDATA = Path(os.environ.get("CONTACTID_REALDATA") or ROOT.parent / "shared" / "realdata")
BRB_MAT = REALDATA / "brb" / "ForcedFrequencyResponses.mat"
BRB_MISSING = (f"the Brake-Reuss beam's data (GPL-3.0, not shipped) are not at {BRB_MAT}: get "
               "ForcedFrequencyResponses.mat from the public repository mattiacenedese/BRBtesting into "
               "$CONTACTID_REALDATA/brb/ (docs/import.md)")
