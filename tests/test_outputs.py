"""Output files: never overwrite silently, never an input, nothing half-written."""
import pytest

from analysis.common.errors import InputError
from app.session.outputs import atomic_output, atomic_replace, check_output, require_free_space, temporary_path


def test_an_existing_output_is_refused_without_force(tmp_path):
    target = tmp_path / "a.toml"
    target.write_text("keep")
    with pytest.raises(InputError, match="exists already"):
        check_output(target)
    assert check_output(target, overwrite=True) == target


def test_an_input_is_never_an_output_even_with_force(tmp_path):
    session = tmp_path / "s.h5"
    session.write_bytes(b"data")
    with pytest.raises(InputError, match="also an input"):
        check_output(tmp_path / "." / "s.h5", inputs=[session], overwrite=True)
    assert session.read_bytes() == b"data"


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "out.csv"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_output(target, overwrite=True) as temp:
            temp.write_text("half")
            raise RuntimeError("disk full")
    assert target.read_text() == "old"
    assert not temporary_path(target).exists()
    with atomic_output(target, overwrite=True) as temp:
        temp.write_text("new")
    assert target.read_text() == "new" and list(tmp_path.iterdir()) == [target]


def test_free_space_is_checked(tmp_path):
    require_free_space(tmp_path, 1)
    with pytest.raises(OSError, match="not enough free space"):
        require_free_space(tmp_path, 1 << 62)


def test_a_file_changed_in_place_is_whole_or_untouched(tmp_path):
    target = tmp_path / "s.h5"
    target.write_text("old")
    target.chmod(0o640)
    with pytest.raises(RuntimeError):
        with atomic_replace(target) as temp:
            temp.write_text("half")
            raise RuntimeError("crash while writing")
    assert target.read_text() == "old" and list(tmp_path.iterdir()) == [target]
    with pytest.raises(OSError, match="not enough free space"):
        with atomic_replace(target, extra_bytes=1 << 62):
            raise AssertionError("never reached: refused before anything is written")
    with atomic_replace(target) as temp:
        temp.write_text("new")
    assert target.read_text() == "new" and target.stat().st_mode & 0o777 == 0o640
    assert list(tmp_path.iterdir()) == [target]


# ----- commands that write sessions: never over an input, never over an earlier demo ---------------------------
def _cli(argv):
    from app.cli import main
    return main(argv)


@pytest.mark.parametrize("flags", [[], ["--overwrite"], ["--force"]])
def test_simulate_refuses_to_write_its_session_over_its_own_plan(tmp_path, capsys, flags):
    plan = tmp_path / "p.toml"
    plan.write_text("[random]\nforce_rms = 0.05\nband = [0.5, 5.0]\nduration = 8.0\n"
                    "[limits]\nmax_force = 5.0\nmax_acceleration = 50.0\n", encoding="utf-8")
    before = plan.read_bytes()
    assert _cli(["simulate", "paper-2dof", str(plan), "-o", str(plan), *flags]) == 2
    # one line of error (the old spelling --force adds its own note before it)
    err = [line for line in capsys.readouterr().err.splitlines() if "old spelling" not in line]
    assert len(err) == 1 and "p.toml" in err[0] and "also an input" in err[0]
    assert plan.read_bytes() == before


def test_acquire_refuses_to_write_its_session_over_its_plan_before_opening_a_port(tmp_path, capsys):
    plan = tmp_path / "p.toml"
    plan.write_text("not even TOML", encoding="utf-8")
    assert _cli(["acquire", str(plan), "-o", str(plan), "--force", "--shaker", "sim://nowhere/shaker",
                 "--daq", "sim://nowhere/daq"]) == 2
    assert "also an input" in capsys.readouterr().err
    assert plan.read_text(encoding="utf-8") == "not even TOML"


@pytest.mark.parametrize("earlier", ["paper-beam.h5", "paper-beam.fitted.toml", "report/kbar.png"])
def test_the_demo_refuses_a_folder_holding_an_earlier_demo_without_overwrite(tmp_path, capsys, earlier):
    out = tmp_path / "demo"
    (out / "report").mkdir(parents=True)
    (out / earlier).write_bytes(b"an earlier demo")
    assert _cli(["demo", "--quick", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert earlier in err and "--overwrite" in err and len(err.strip().splitlines()) == 1
    assert (out / earlier).read_bytes() == b"an earlier demo"
    assert sorted(p.name for p in out.rglob("*")) == sorted({"report", earlier.split("/")[-1]})


@pytest.mark.slow
@pytest.mark.parametrize("signum, status, said", [(2, 130, "interrupted"), (15, 143, "stopped")])
def test_an_interrupted_demo_with_overwrite_leaves_the_earlier_session_and_keeps_the_new_one_beside_it(
        tmp_path, signum, status, said):
    """The demo interrupted (Ctrl-C, SIGTERM) while it measures: the earlier session is untouched, the lines
    measured are kept beside it as paper-beam.incomplete.h5, and the command says so with the signal's status."""
    import signal
    import subprocess
    import sys
    import threading

    import h5py

    out = tmp_path / "demo"
    out.mkdir()
    (out / "paper-beam.h5").write_bytes(b"a complete earlier session")
    # Ctrl-C as a shell delivers it: a test run started in the background has SIGINT ignored, and a child
    # inherits that (Python then installs no KeyboardInterrupt handler)
    # faulthandler: a child that does not end is sent SIGABRT and prints where every thread of it stands
    proc = subprocess.Popen([sys.executable, "-X", "faulthandler", "-m", "app.cli", "demo", "--quick", "--overwrite",
                             "--out", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    err, measuring = [], threading.Event()

    def read_progress():
        for line in proc.stderr:
            err.append(line)
            if " lines " in line:                  # the progress of a stepped sine: lines are in
                measuring.set()
        measuring.set()

    reader = threading.Thread(target=read_progress, daemon=True)
    reader.start()
    assert measuring.wait(300)                     # a generous guard: a loaded machine starts slowly
    proc.send_signal(signum)
    try:
        code = proc.wait(timeout=300)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)
        proc.wait(timeout=60)
        reader.join(10)
        pytest.fail("the demo did not end within 300 s of the signal; its threads then:\n" + "".join(err[-200:]))
    assert code == status
    reader.join(10)
    err = "".join(err)
    assert said in err
    assert (out / "paper-beam.h5").read_bytes() == b"a complete earlier session"
    kept = out / "paper-beam.incomplete.h5"
    assert "left as it was" in err and str(kept) in err
    with h5py.File(kept, "r") as f:
        assert len(f["runs"]) >= 1
    assert not list(out.glob(".*partial"))
