"""The corners stage's forked workers must not inherit the parent's undeleted video decoders.

A child of ``extract_corners_parallel`` is forked from a process that may hold unreachable
PyAV containers (reference cycles not yet collected) whose decoders run slice threads. The
threads do not exist in the child; freeing such a container there (its collector running)
waited forever for them to join: the suite hung in test_media's damaged-recording test.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

HERE = Path(__file__).resolve().parents[3]

CHILD = textwrap.dedent("""
    import functools, gc, sys
    sys.path.insert(0, {here!r})
    from tests.helpers.board_images import BOARD, write_h264
    from cvsflow.corners.extract import extract_corners_parallel
    from cvsflow.io.media import iter_video_gray

    def collected_first(path, start, stop):
        gc.collect()  # in the child: the collector meets whatever it inherited
        yield from iter_video_gray(path, start, stop)

    path = {path!r}
    write_h264(path, 90, gop=15)
    # a decoder left running in an unreachable cycle, as a generator read part-way leaves it
    gen = iter_video_gray(path)
    next(gen)
    cycle = [gen]
    cycle.append(cycle)
    del gen, cycle
    table = extract_corners_parallel(functools.partial(collected_first, path), 90, BOARD,
                                     n_workers=2, restart_every=45, log_every=0)
    print("frames", table["frame"].nunique())
""")


def test_forked_corner_workers_do_not_free_the_parents_decoders(tmp_path):
    code = CHILD.format(here=str(HERE), path=str(tmp_path / "v.mp4"))
    # its own process group, so that hung workers are killed with it
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        raise AssertionError("extract_corners_parallel hung in a forked worker") from None
    assert proc.returncode == 0, err[-2000:]
    assert "frames 90" in out
