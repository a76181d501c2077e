"""The disk cache of compiled code is keyed on the sources (analysis/common/compiled.py): a cached kernel that
calls a compiled helper of another file is recompiled when that file changes, where numba's own cache, which checks
the kernel's file only, keeps running the old helper."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

from analysis.common.compiled import key_cache_on, source_key

ROOT = Path(__file__).resolve().parents[1]

_KERNEL = """\
from analysis.common.compiled import njit
from .helper import step


@njit(cache=True)
def kernel(x):
    return step(x) * 10.0
"""
_HELPER = """\
from numba import njit


@njit
def step(x):
    return x + {shift}
"""
_RUN = """\
import sys
from pathlib import Path
import numba
from analysis.common.compiled import key_cache_on
tmp = Path(sys.argv[1])
if sys.argv[2] == "keyed":
    assert key_cache_on([tmp / "pkg"], base=tmp / "keyed") is not None
else:
    numba.config.CACHE_DIR = str(tmp / "plain")   # numba's own cache: the kernel's file is its only key
sys.path.insert(0, str(tmp))
from pkg.kernel import kernel
print(kernel(1.0))
"""


def _package(tmp: Path, shift: int) -> None:
    (tmp / "pkg").mkdir(exist_ok=True)
    (tmp / "pkg" / "__init__.py").write_text("")
    (tmp / "pkg" / "helper.py").write_text(_HELPER.format(shift=shift))
    kernel = tmp / "pkg" / "kernel.py"
    if not kernel.exists():
        kernel.write_text(_KERNEL)


def _run(tmp: Path, mode: str) -> float:
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONDONTWRITEBYTECODE="1")
    out = subprocess.run([sys.executable, "-c", _RUN, str(tmp), mode], env=env, cwd=tmp,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return float(out.stdout.split()[-1])


@pytest.mark.slow
def test_a_kernel_runs_the_helper_of_today_after_the_helpers_file_changed(tmp_path):
    _package(tmp_path, shift=1)
    assert _run(tmp_path, "plain") == 20.0
    assert _run(tmp_path, "keyed") == 20.0
    _package(tmp_path, shift=2)                     # the helper's file changes, the kernel's does not
    assert _run(tmp_path, "plain") == 20.0           # numba's own cache: the old helper runs (the fault)
    assert _run(tmp_path, "keyed") == 30.0           # keyed on the sources: recompiled against the new one


def test_the_key_follows_every_source_and_only_the_sources(tmp_path):
    room = tmp_path / "room"
    (room / "sub").mkdir(parents=True)
    (room / "a.py").write_text("A = 1\n")
    (room / "sub" / "b.py").write_text("B = 2\n")
    (room / "notes.txt").write_text("not a source")
    key = source_key([room])
    assert len(key) == 16 and source_key([room]) == key
    (room / "notes.txt").write_text("changed")
    assert source_key([room]) == key
    (room / "sub" / "b.py").write_text("B = 3\n")
    changed = source_key([room])
    assert changed != key
    (room / "sub" / "b.py").rename(room / "b.py")    # same bytes, another place
    assert source_key([room]) not in (key, changed)


def test_an_unwritable_base_leaves_numbas_choice(tmp_path):
    import numba
    before = numba.config.CACHE_DIR
    blocked = tmp_path / "file"
    blocked.write_text("a file where the directory would go")
    assert key_cache_on([tmp_path], base=blocked) is None
    assert numba.config.CACHE_DIR == before


def test_directories_of_other_keys_unused_for_long_are_removed(tmp_path):
    import numba
    before = numba.config.CACHE_DIR
    room = tmp_path / "room"
    room.mkdir()
    (room / "a.py").write_text("A = 1\n")
    base = tmp_path / "cache"
    old, recent, other = base / ("0" * 16), base / ("1" * 16), base / "not-a-key"
    for directory in (old, recent, other):
        directory.mkdir(parents=True)
    long_ago = 1e9
    os.utime(old, (long_ago, long_ago))
    os.utime(other, (long_ago, long_ago))
    try:
        made = key_cache_on([room], base=base)
        assert made == base / source_key([room]) and made.is_dir()
        assert numba.config.CACHE_DIR == str(made)
        assert not old.exists() and recent.exists() and other.exists()
    finally:
        numba.config.CACHE_DIR = before


_FACTORY = """\
import numpy as np
from numba import njit
from analysis.common.compiled import cfunc_fixed, njit_fixed


@njit
def plus_one(x):
    return x + 1.0


@njit
def plus_two(x):
    return x + 2.0


def make(kernel, scale, fixed):
    decorate = njit_fixed() if fixed else njit(cache=True)

    @decorate
    def outer(x):
        return kernel(x) * scale
    return outer


def make_callback(kernel, scale):
    @cfunc_fixed("float64(float64)")
    def callback(x):
        return kernel(x) * scale
    return callback


def make_filler(kernel):
    @njit
    def inner(x):
        return kernel(x) + 0.5

    @njit_fixed()
    def fill(n):
        out = np.empty(n)
        for i in range(n):
            out[i] = inner(float(i))
        return out
    return fill
"""
_FACTORY_RUN = """\
import sys
from pathlib import Path
from analysis.common.compiled import key_cache_on
tmp = Path(sys.argv[1])
assert key_cache_on([tmp / "pkg"], base=tmp / "keyed") is not None
sys.path.insert(0, str(tmp))
from pkg.factory import make, make_callback, plus_one, plus_two
for kernel, scale in ((plus_one, 10), (plus_two, 10), (plus_one, 100)):
    outer = make(kernel, scale, sys.argv[2] == "fixed")
    print(outer(1.0), sum(outer.stats.cache_hits.values()))
    if sys.argv[2] == "fixed":
        callback = make_callback(kernel, scale)
        print(callback.ctypes(1.0), callback.cache_hits)
"""


def _run_factory(tmp: Path, mode: str) -> list[tuple[float, int]]:
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONDONTWRITEBYTECODE="1")
    out = subprocess.run([sys.executable, "-c", _FACTORY_RUN, str(tmp), mode], env=env, cwd=tmp,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return [(float(value), int(hits)) for value, hits in (line.split() for line in out.stdout.splitlines())]


@pytest.mark.slow
def test_a_function_compiled_around_another_is_found_again_by_the_next_process_and_told_apart(tmp_path):
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "__init__.py").write_text("")
    (tmp_path / "pkg" / "factory.py").write_text(_FACTORY)
    right = [20.0, 30.0, 200.0]
    # numba's own cache keys the closure on a pickle of the kernel, new in every process: never found again
    assert _run_factory(tmp_path, "plain") == [(v, 0) for v in right]
    assert _run_factory(tmp_path, "plain") == [(v, 0) for v in right]
    # keyed on the description: compiled once, then loaded, each closure its own entry (kernel and scale); the
    # same for C callbacks
    twice = [v for v in right for _ in range(2)]
    assert _run_factory(tmp_path, "fixed") == [(v, 0) for v in twice]
    assert _run_factory(tmp_path, "fixed") == [(v, 1) for v in twice]


_APART = """\
import sys
from pathlib import Path
from analysis.common.compiled import key_cache_on
tmp = Path(sys.argv[1])
assert key_cache_on([tmp / "pkg"], base=tmp / "keyed") is not None
sys.path.insert(0, str(tmp))
from pkg.factory import make_callback, make_filler, plus_one, plus_two
for name in sys.argv[2:]:
    kernel = {"one": plus_one, "two": plus_two}[name]
    fill, callback = make_filler(kernel), make_callback(kernel, 10)
    print(name, fill(3).tolist(), callback.ctypes(1.0), callback.address != 0)
"""


@pytest.mark.slow
def test_closures_of_one_factory_keep_files_of_their_own_and_load_together(tmp_path):
    """numba names a cache's files after the function: the closures of one factory would share one index, whose
    entries two processes saving at once can cross (a closure then loads another's code; seen as a law's march
    failing to return its array after the suite's two workers had compiled marches side by side). Each closure
    has files of its own, and closures compiled first in two processes load together into a third."""
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "__init__.py").write_text("")
    (tmp_path / "pkg" / "factory.py").write_text(_FACTORY)
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONDONTWRITEBYTECODE="1")

    def run(*names):
        out = subprocess.run([sys.executable, "-c", _APART, str(tmp_path), *names], env=env, cwd=tmp_path,
                             capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        return out.stdout.splitlines()

    one, two = "one [1.5, 2.5, 3.5] 20.0 True", "two [2.5, 3.5, 4.5] 30.0 True"
    assert run("one") == [one]
    assert run("two") == [two]               # each the first closure its process compiled
    assert run("one", "two") == [one, two]   # both loaded from the cache into one process
    assert run("two", "one") == [two, one]
    for name in ("fill", "callback"):
        assert len(list((tmp_path / "keyed").rglob(f"*{name}_*.nbi"))) == 2, name


def _save_side_by_side(tmp: Path, save) -> tuple:
    """Two savers of one index, each in a thread, each reading the index and then waiting (up to 1 s) for the
    other to have read it too: the interleaving of two processes saving at once, where nothing serialises them.
    Returns what a third reader loads for each key."""
    import threading

    from numba.core.caching import IndexDataCacheFile

    read = IndexDataCacheFile._load_index
    both_read = threading.Barrier(2, timeout=1.0)

    def read_then_wait(self):
        overloads = read(self)
        try:
            both_read.wait()
        except threading.BrokenBarrierError:
            pass
        return overloads

    def saver(key, data):
        return lambda: save(IndexDataCacheFile(str(tmp), "f", (1.0, 1)), key, data)

    IndexDataCacheFile._load_index = read_then_wait
    try:
        threads = [threading.Thread(target=saver("first", ("one",))),
                   threading.Thread(target=saver("second", ("two",)))]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        IndexDataCacheFile._load_index = read
    reader = IndexDataCacheFile(str(tmp), "f", (1.0, 1))
    return reader.load("first"), reader.load("second")


def test_two_saves_of_one_function_at_once_keep_their_own_entries(tmp_path):
    from numba.core.caching import IndexDataCacheFile

    from analysis.common import compiled

    assert IndexDataCacheFile.save.__qualname__.startswith("_serialised")
    (tmp_path / "plain").mkdir()
    (tmp_path / "locked").mkdir()
    crossed = _save_side_by_side(tmp_path / "plain", compiled._numba_save)      # numba's own save
    assert crossed != (("one",), ("two",))     # the fault: a key lost, and the other's pointing at its data or not
    assert _save_side_by_side(tmp_path / "locked", IndexDataCacheFile.save) == (("one",), ("two",))


def test_a_ctrl_c_during_a_compile_acts_once_the_function_is_compiled(ctrl_c):
    """LLVM hands the object code it emits to a ctypes callback that swallows an exception raised in it: a Ctrl-C
    there was lost and the function left without its code (``RuntimeError: no compiled object yet`` at its next
    call, exit 1 where the command was interrupted). A compile is held whole (analysis/common/compiled.py). The
    signal comes from the typing of a call the function makes: within its compile, whatever the machine's load."""
    import signal

    import numba
    from numba.extending import overload

    sent = []

    def marked(x):
        return x

    @overload(marked)
    def _typed(x):
        if not sent:                                   # once: a second signal in a held step acts at once
            sent.append(True)
            signal.raise_signal(signal.SIGINT)
        return lambda x: x + 1.0

    @numba.njit
    def uses_it(x):                                    # not disk-cached: it compiles here
        return marked(x) * 2.0

    with pytest.raises(KeyboardInterrupt):
        uses_it(1.5)
    assert sent and uses_it.signatures                  # compiled whole before the signal acted
    assert uses_it(1.5) == 5.0
