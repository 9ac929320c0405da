"""Removal and replacement inside an output folder hold against a folder swapped for a link while
they run (issue 30, high 2): `reconstruct` checked a path, then unlinked the resolved path, and with
the folder exchanged for a link in a loop (renameat2) 3 of 16 runs deleted files outside `-o`."""
from __future__ import annotations

import ctypes
import os
import threading

import pytest

from spikesim import outputs

RENAME_EXCHANGE = 2
AT_FDCWD = -100


def _renameat2():
    libc = ctypes.CDLL(None, use_errno=True)
    fn = getattr(libc, "renameat2", None)
    if fn is None:
        pytest.skip("no renameat2 in this libc")
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    return fn


SWAPPER = """
import ctypes, sys, time
libc = ctypes.CDLL(None, use_errno=True)
f = libc.renameat2
f.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
a, b = sys.argv[1].encode(), sys.argv[2].encode()
end = time.monotonic() + 60
while time.monotonic() < end:
    f(-100, a, -100, b, 2)
"""


@pytest.fixture()
def swapping(tmp_path):
    """out/png (a real folder) exchanged with out/png_swap (a link to `outside`) in a loop, by
    another process (no GIL between the swaps and the code under test)."""
    import subprocess
    import sys

    _renameat2()
    outside = tmp_path / "outside"
    outside.mkdir()
    out = tmp_path / "out"
    (out / "png").mkdir(parents=True)
    (out / "png_swap").symlink_to(outside)
    names = [f"step_{i:06d}.png" for i in range(40)]
    for n in names:
        (outside / n).write_text("the user's file")
        (out / "png" / n).write_text("an earlier run's frame")
    proc = subprocess.Popen([sys.executable, "-c", SWAPPER, str(out / "png"), str(out / "png_swap")])
    yield out, outside, names
    proc.kill()
    proc.wait()


def _for(seconds, fn):
    import time
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        fn()


def test_remove_never_deletes_through_a_swapped_folder(swapping):
    out, outside, names = swapping

    def once():
        for n in names:
            try:
                outputs.remove(out, "png", n)
            except (ValueError, OSError):
                pass  # refused: the folder was a link at that moment
    _for(3.0, once)
    assert sorted(p.name for p in outside.iterdir()) == names
    assert all((outside / n).read_text() == "the user's file" for n in names)


def test_move_into_never_writes_through_a_swapped_folder(swapping, tmp_path):
    out, outside, names = swapping
    stage = tmp_path / "stage"
    stage.mkdir()

    def once():
        for n in names:
            (stage / n).write_text("new frame")
            try:
                outputs.move_into(stage / n, out, "png", n)
            except (ValueError, OSError):
                (stage / n).unlink(missing_ok=True)
    _for(3.0, once)
    assert all((outside / n).read_text() == "the user's file" for n in names)


def test_parent_fd_refuses_a_link_on_the_way(tmp_path):
    (tmp_path / "real").mkdir()
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "png").symlink_to(tmp_path / "real")
    with pytest.raises(ValueError, match="symlink|outside the output root"):
        with outputs.parent_fd(tmp_path / "out", "png", "x.png"):
            pass
    outputs.remove(tmp_path / "missing_root", "a", "b")  # nothing there: nothing to delete
