"""What several ``cvsflow`` subcommands share: the help epilog and the ``--inner`` parser."""

from __future__ import annotations

import argparse

EPILOG = """\
examples:
  cvsflow calibrate stills/ --inner 9x6 --square-m 0.025 --out calib/
  cvsflow export camera results/demo --format kalibr --out camchain.yaml
  cvsflow export trajectory results/demo --out-dir traj/
  cvsflow init recordings/lab1 --out my_session.yaml
  cvsflow run my_session.yaml --cores 2
  cvsflow demo cvsflow-demo/
`cvsflow COMMAND --help` explains each command's options.

board convention: cvsflow's config counts SQUARES (board.squares_x, squares_y); OpenCV and
Kalibr count INNER CORNERS (one fewer each way). `--inner 9x6` is 10x7 squares.

exit codes: 0 ok, 1 cvsflow error (one line naming the file), 2 usage error;
`cvsflow run` returns snakemake's exit code.
"""


def _parse_grid(text: str, flag: str, example: str, least: int, what: str) -> tuple[int, int]:
    """``AxB`` of ``flag`` as two ints of at least ``least`` (argparse's error otherwise)."""
    try:
        a, b = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{flag} {text!r}: expected {example}") from exc
    if a < least or b < least:
        raise argparse.ArgumentTypeError(f"{flag} {text!r}: expected at least {least}x{least} {what}")
    return a, b


def _parse_squares(text: str) -> tuple[int, int]:
    return _parse_grid(text, "--charuco", "SXxSY squares, e.g. 7x5", 3, "squares")


def _parse_inner(text: str) -> tuple[int, int]:
    return _parse_grid(text, "--inner", "NXxNY, e.g. 9x6", 2, "inner corners")
