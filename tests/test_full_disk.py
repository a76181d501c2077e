"""A full disk while `import`, `import --append`, `export` or `analyze -o` writes: one line saying what was not
written and why, exit status 2, the originals intact and nothing left behind (no partial file, no empty folder)."""
import shutil

import pytest

from app.cli import main
from test_session_integrity import FILL, MODEL, needs_private_mount, on_small_disk, write_session

pytestmark = [needs_private_mount, pytest.mark.slow]


@pytest.fixture(scope="module")
def originals(tmp_path_factory):
    folder = tmp_path_factory.mktemp("full")
    write_session(folder / "s.h5")
    (folder / "model.toml").write_text(MODEL)
    assert main(["export", str(folder / "s.h5"), "--uff", str(folder / "a.uff"), "--one-file"]) == 0
    return folder


def run_on_full_disk(tmp_path, originals, command: str):
    """Copy the originals onto a private 2 MiB disk, fill it, run ``command`` (contactid's arguments)."""
    for name in ("s.h5", "model.toml", "a.uff"):
        shutil.copy(originals / name, tmp_path / name)
    on_small_disk(tmp_path, "2m", 'cp "$OUT/s.h5" "$OUT/model.toml" "$OUT/a.uff" "$DISK"/ && ' + FILL +
                  f'$PY -m app.cli {command} > "$OUT/stdout" 2> "$OUT/stderr"; echo $? > "$OUT/rc"; '
                  'cp "$DISK/s.h5" "$OUT/after.h5"; ls -A "$DISK" > "$OUT/listing"')
    err = (tmp_path / "stderr").read_text().strip()
    assert (tmp_path / "rc").read_text().strip() == "2", err
    assert err.count("\n") == 0 and err.startswith("contactid: error: ") and "--debug" not in err, err
    assert (tmp_path / "after.h5").read_bytes() == (originals / "s.h5").read_bytes()
    assert sorted((tmp_path / "listing").read_text().split()) == ["a.uff", "fill", "model.toml", "s.h5"]
    return err


@pytest.mark.parametrize("command,names", [
    ('import "$DISK/a.uff" -o "$DISK/new.h5"', ["new.h5", "not enough free space to write the session"]),
    ('import "$DISK/a.uff" -o "$DISK/s.h5" --append', ["s.h5", "not enough free space to write the session"]),
    ('export "$DISK/s.h5" --uff "$DISK/out.uff" --per-run', ["out_sine_0.4N_up.uff", "export UFF58"]),
    ('export "$DISK/s.h5" --csv "$DISK/csv"', ["sine_0.4N_up.csv", "not written: No space left on device"]),
    ('analyze "$DISK/s.h5" "$DISK/model.toml" --no-history -o "$DISK/fitted.toml"',
     ["fitted.toml", "not enough free space to write the fitted model"]),
], ids=["import", "append", "export-uff", "export-csv", "analyze-o"])
def test_a_full_disk_is_one_line_naming_what_was_not_written(tmp_path, originals, command, names):
    err = run_on_full_disk(tmp_path, originals, command)
    for name in names:
        assert name in err, err
