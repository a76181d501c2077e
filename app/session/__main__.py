"""The session's child processes, started from the checkout's root:

- ``python -m app.session``: the writer process, serving one session file over stdin/stdout
  (:func:`app.session.file.main`; started by :class:`app.session.SessionWriter`);
- ``python -m app.session salvage SOURCE TARGET image|swmr SKIP_JSON``: one attempt at reading what can be read
  of a damaged session (:mod:`app.session.salvage`; started by ``recover_session``).
"""
import sys

if sys.argv[1:2] == ["salvage"]:
    from app.session.salvage import child_main

    sys.exit(child_main(sys.argv[2:]))

import os

from app.session.file import main

status = main()
# the file is closed and every reply sent: the interpreter's teardown of NumPy and h5py (some 15 ms of CPU, a
# tenth of the writer's work in a simulated campaign) has nothing left to do
sys.stderr.flush()
os._exit(status)
