"""Progress lines for long work: units done, rate and time left, live on a terminal, in the log.

A stage passes a :class:`Progress` as the ``progress`` callable of a long package function
(``progress(n)``: n units done so far); the function knows nothing of terminals or logs. On a
terminal the line is redrawn in place; every :data:`PROGRESS_LOG_EVERY_S` it is also logged at
INFO, which :func:`cvsflow.io.logs.stage_logging` writes into the job's log (and onto a console
that is not a terminal: a cluster job's output, a redirected run). :func:`console_handler` is
the stderr handler that keeps the live line and the log lines from running into each other.
"""

from __future__ import annotations

import logging
import sys
import time

#: Seconds between progress lines in a job's log (and on a console that is not a terminal).
PROGRESS_LOG_EVERY_S = 10.0
#: Seconds between redraws of the live progress line on a terminal.
PROGRESS_LIVE_EVERY_S = 0.5
_CLEAR_LINE = "\r\x1b[K"


def _duration(seconds: float) -> str:
    """``45 s``, ``3 min 20 s``, ``1 h 05 min``."""
    s = int(round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


class Progress:
    """A progress line for long work: units done, rate and time left.

    Called with the number of units done so far (``progress(n)``; cheap, call it per unit), it
    redraws one line on the console when stderr is a terminal (every
    :data:`PROGRESS_LIVE_EVERY_S`) and logs the line at INFO every :data:`PROGRESS_LOG_EVERY_S`
    (into the job's log under :func:`cvsflow.io.logs.stage_logging`, and on a console that is not
    a terminal).
    Work shorter than that leaves no line in the log.

    Parameters
    ----------
    what : str
        What is done, e.g. ``"corners"``.
    total : int, optional
        Units in all (for the share and the time left).
    unit : str
        The units' name, plural (``"frames"``).
    logger : logging.Logger, optional
        Where the periodic line goes (default ``cvsflow.progress``).
    live : bool, optional
        Draw the live line; default: stderr is a terminal.
    """

    def __init__(self, what: str, total: int | None = None, unit: str = "frames",
                 logger: logging.Logger | None = None, live: bool | None = None):
        self.what, self.total, self.unit = what, total, unit
        self.log = logger or logging.getLogger("cvsflow.progress")
        self.live = _is_terminal(sys.stderr) if live is None else live
        self.done = 0
        self._t0 = time.perf_counter()
        self._last_live = self._last_log = self._t0
        self._first = None  # (time, units) of the first call: the rate leaves out the set-up
        self._drawn = False

    def line(self) -> str:
        """The progress line now: ``corners: 1200 of 2700 frames (44 %), 410 frames/s, 4 s left``.

        Returns
        -------
        str
        """
        now = time.perf_counter()
        t_first, n_first = self._first or (self._t0, 0)
        if self.done > n_first and now > t_first:
            rate = (self.done - n_first) / (now - t_first)
        else:
            rate = self.done / (now - self._t0) if now > self._t0 else 0.0
        text = f"{self.what}: {self.done}"
        if self.total:
            text += f" of {self.total} {self.unit} ({100 * self.done / self.total:.0f} %)"
        else:
            text += f" {self.unit}"
        text += f", {rate:.3g} {self.unit}/s"
        if self.total and rate > 0:
            text += f", {_duration(max(self.total - self.done, 0) / rate)} left"
        return text

    def __call__(self, done: int) -> None:
        """Record ``done`` units; draw or log the line when it is time.

        Parameters
        ----------
        done : int
            Units done so far.

        Returns
        -------
        None
        """
        self.done = int(done)
        now = time.perf_counter()
        if self._first is None:
            self._first = (now, self.done)
        if self.live and now - self._last_live >= PROGRESS_LIVE_EVERY_S:
            self._last_live = now
            sys.stderr.write(_CLEAR_LINE + self.line())
            sys.stderr.flush()
            self._drawn = True
        if now - self._last_log >= PROGRESS_LOG_EVERY_S:
            self._last_log = now
            self.log.info(self.line(), extra={"progress": True})

    def close(self) -> None:
        """Clear the live line (the stage's own summary line follows).

        Returns
        -------
        None
        """
        if self._drawn:
            sys.stderr.write(_CLEAR_LINE)
            sys.stderr.flush()
            self._drawn = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class _ClearLineFormatter(logging.Formatter):
    """Prefix each record with a return and clear-to-end-of-line: it overwrites a live line."""

    def format(self, record):
        return _CLEAR_LINE + super().format(record)


def _not_progress(record) -> bool:
    return not getattr(record, "progress", False)


def console_handler(stream=None, fmt: str | None = None) -> logging.Handler:
    """A stderr handler for a stage's log records that shares the terminal with a live line.

    Parameters
    ----------
    stream : file, optional
        Default ``sys.stderr``.
    fmt : str, optional
        The records' format.

    Returns
    -------
    logging.Handler
        On a terminal: each record first clears the line (a live progress line), and the
        periodic progress records are left out (the live line shows them). Elsewhere: a plain
        ``StreamHandler``, progress records included.
    """
    stream = stream or sys.stderr
    handler = logging.StreamHandler(stream)
    if _is_terminal(stream):
        handler.setFormatter(_ClearLineFormatter(fmt))
        handler.addFilter(_not_progress)
    else:
        handler.setFormatter(logging.Formatter(fmt))
    return handler


def _is_terminal(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # a closed or unusual stream
        return False
