"""Progress lines: units done, rate and time left; live on a terminal, every 10 s in the log."""

import io
import logging

import pytest

from cvsflow.io import progress as pg
from cvsflow.io.logs import stage_logging


class Clock:
    """A perf_counter that moves only when told."""

    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


class Terminal(io.StringIO):
    def isatty(self):
        return True


@pytest.fixture
def clock(monkeypatch):
    c = Clock()
    monkeypatch.setattr(pg.time, "perf_counter", c)
    return c


def test_line_says_done_share_rate_and_time_left(clock):
    """Halfway through 2700 frames in 5 s: 270 frames/s and 5 s left; later, minutes and hours."""
    p = pg.Progress("corners", 2700, "frames", live=False)
    clock.t += 5.0
    p(1350)
    assert p.line() == "corners: 1350 of 2700 frames (50 %), 270 frames/s, 5 s left"
    p2 = pg.Progress("synth", 100000, "frames", live=False)
    clock.t += 10.0
    p2(500)
    assert p2.line().endswith("50 frames/s, 33 min 10 s left")
    p3 = pg.Progress("folds", None, "folds", live=False)
    clock.t += 2.0
    p3(3)
    assert p3.line() == "folds: 3 folds, 1.5 folds/s"
    assert pg._duration(3 * 3600 + 65) == "3 h 01 min"


def test_live_line_redraws_in_place_and_is_cleared(clock, monkeypatch):
    """On a terminal: the line redrawn (return, clear to the end) at most every 0.5 s, cleared
    at the end so the stage's own summary starts on a clean line."""
    term = Terminal()
    monkeypatch.setattr(pg.sys, "stderr", term)
    with pg.Progress("corners", 10, "frames") as p:
        p(1)  # too soon: nothing drawn
        clock.t += 0.6
        p(2)
        clock.t += 0.1
        p(3)  # too soon again
        clock.t += 0.6
        p(4)
    out = term.getvalue()
    assert out.count("\r\x1b[K") == 3 and "corners: 2 of 10" in out and "corners: 4 of 10" in out
    assert "corners: 3 of 10" not in out and out.endswith("\r\x1b[K")


def test_log_gets_a_line_every_ten_seconds(clock, caplog):
    """Every PROGRESS_LOG_EVERY_S a record (marked progress) goes to the log; short work logs none."""
    caplog.set_level(logging.INFO)
    p = pg.Progress("heldout_se3", 5, "folds", logging.getLogger("cvsflow.stage.x"), live=False)
    for k in range(1, 6):
        clock.t += 4.0
        p(k)
    lines = [r for r in caplog.records if getattr(r, "progress", False)]
    assert [r.getMessage() for r in lines] == ["heldout_se3: 3 of 5 folds (60 %), 0.25 folds/s, 8 s left"]


def test_console_handler_shares_a_terminal_with_the_live_line():
    """On a terminal each record clears the live line first and progress records stay out (the
    live line shows them); elsewhere (a cluster job's output) progress records are printed."""
    log = logging.getLogger("test.progress.console")
    log.propagate = False
    for stream, cleared, shown in ((Terminal(), True, False), (io.StringIO(), False, True)):
        handler = pg.console_handler(stream, "%(message)s")
        log.addHandler(handler)
        log.warning("a warning")
        log.warning("5 of 9 frames", extra={"progress": True})
        log.removeHandler(handler)
        out = stream.getvalue()
        assert out.startswith("\r\x1b[K" if cleared else "a warning")
        assert ("5 of 9 frames" in out) is shown


def test_stage_log_holds_the_progress_lines(tmp_path, clock):
    """Under stage_logging the periodic line lands in the job's log file."""
    with stage_logging(tmp_path / "s.log", "corners") as log:
        p = pg.Progress("corners", 100, "frames", log, live=False)
        clock.t += 11.0
        p(40)
    text = (tmp_path / "s.log").read_text()
    assert "corners: 40 of 100 frames (40 %), 3.64 frames/s, 16 s left" in text
