"""Output files: never overwrite silently, never an input, nothing half-written."""
import pytest

from analysis.errors import InputError
from app.outputs import atomic_output, atomic_replace, check_output, require_free_space, temporary_path


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
