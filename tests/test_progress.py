"""A long command's progress line (app/progress.py): rewritten in place on a terminal, plain lines in a log."""
import io
import time

import pytest

from app.progress import Progress


class Terminal(io.StringIO):
    def isatty(self):
        return True


def wait_for(stream, text):
    for _ in range(500):                     # until the ticker has written (no timing is asserted)
        if text in stream.getvalue():
            return
        time.sleep(0.01)
    raise AssertionError(f"{text!r} never written: {stream.getvalue()!r}")


def test_a_log_gets_plain_lines_naming_the_phase():
    log = io.StringIO()
    with Progress("analyze", stream=log, interval=0.01) as progress:
        progress.phase("ranking the missing effects")
        wait_for(log, "ranking")
    lines = log.getvalue().splitlines()
    assert lines and all(line.startswith("analyze: ") and line.endswith(" s)") for line in lines)
    assert "\r" not in log.getvalue()


def test_a_terminal_gets_one_line_rewritten_and_cleared_at_the_end():
    tty = Terminal()
    with Progress("analyze", stream=tty, interval=0.01) as progress:
        progress.phase("identifying the elements")
        wait_for(tty, "identifying")
    text = tty.getvalue()
    assert "\n" not in text and text.startswith("\ranalyze: ") and text.endswith("\r\033[K")


def test_a_short_command_prints_nothing():
    log = io.StringIO()
    with Progress("analyze", stream=log, interval=60.0) as progress:
        progress.phase("reading the session")
    assert log.getvalue() == ""


@pytest.mark.slow
def test_analyze_writes_plain_progress_lines_in_a_log(tmp_path, capsys, monkeypatch):
    """``analyze`` with stderr not a terminal: plain lines naming its phases, and the report on stdout."""
    import app.progress
    from app.cli import main
    from test_session_integrity import MODEL, write_session

    write_session(tmp_path / "s.h5")
    (tmp_path / "m.toml").write_text(MODEL)
    monkeypatch.setattr(app.progress, "LOG_INTERVAL", 0.02)
    assert main(["analyze", str(tmp_path / "s.h5"), str(tmp_path / "m.toml"), "--no-history"]) == 0
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert lines and all(line.startswith("analyze: ") and line.endswith(" s)") for line in lines)
    assert "\r" not in err and "FRF error of the model" in out
