"""What several ``cvsflow`` subcommands share: the help epilog and the ``--inner`` parser."""

from __future__ import annotations

import argparse

EPILOG = """\
examples:
  cvsflow calibrate stills/ --inner 9x6 --square-m 0.025 --out calib/
  cvsflow export camera results/demo --format kalibr --out camchain.yaml
  cvsflow export trajectory results/demo --out-dir traj/
  cvsflow init recordings/lab1 --out my_session.yaml
  cvsflow run --cores 2 --configfile my_session.yaml results/lab1/comparison.yaml
`cvsflow COMMAND --help` explains each command's options.

board convention: cvsflow's config counts SQUARES (board.squares_x, squares_y); OpenCV and
Kalibr count INNER CORNERS (one fewer each way). `--inner 9x6` is 10x7 squares.

exit codes: 0 ok, 1 cvsflow error (one line naming the file), 2 usage error;
`cvsflow run` returns snakemake's exit code.
"""


def _parse_squares(text: str) -> tuple[int, int]:
    try:
        sx, sy = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"--charuco {text!r}: expected SXxSY squares, e.g. 7x5") from exc
    if sx < 3 or sy < 3:
        raise argparse.ArgumentTypeError(f"--charuco {text!r}: expected at least 3x3 squares")
    return sx, sy


def _parse_inner(text: str) -> tuple[int, int]:
    try:
        nx, ny = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"--inner {text!r}: expected NXxNY, e.g. 9x6") from exc
    if nx < 2 or ny < 2:
        raise argparse.ArgumentTypeError(f"--inner {text!r}: expected at least 2x2 inner corners")
    return nx, ny
