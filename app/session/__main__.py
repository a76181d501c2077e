"""The session writer process: ``python -m app.session`` serves one session file over stdin/stdout
(:func:`app.session.file.main`; started by :class:`app.session.SessionWriter`)."""
import sys

from app.session.file import main

sys.exit(main())
