"""What several ``cvsflow`` subcommands share: the help epilog, the ``--inner`` parser and the board
options (``--inner`` or ``--target``)."""

from __future__ import annotations

import argparse

EPILOG = """\
examples:
  cvsflow calibrate stills/ --inner 9x6 --square-m 0.025 --out calib/
  cvsflow calibrate frames/ --target april_6x6.yaml --out calib/    (a Kalibr target file)
  cvsflow export camera results/demo --format kalibr --out camchain.yaml
  cvsflow export trajectory results/demo --out-dir traj/
  cvsflow init recordings/lab1 --out my_session.yaml
  cvsflow run my_session.yaml --cores 2
  cvsflow demo cvsflow-demo/
`cvsflow COMMAND --help` explains each command's options.

board convention: cvsflow's config counts SQUARES (board.squares_x, squares_y); OpenCV and
Kalibr count INNER CORNERS (one fewer each way). `--inner 9x6` is 10x7 squares. `--target FILE`
reads a Kalibr target YAML instead: an aprilgrid (Kalibr's target frame, corner id 4 * tag + k)
or a checkerboard (targetCols x targetRows inner corners; Kalibr's frame has x and y swapped).

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


def add_board_args(parser, charuco: bool = False, required: bool = True) -> None:
    """The board options of a command: ``--inner NXxNY`` with ``--square-m`` (a chessboard),
    ``--charuco SXxSY`` (when ``charuco``), or ``--target FILE`` (a Kalibr target file), one
    of them required.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The subcommand's parser.
    charuco : bool
        Offer ``--charuco`` too.
    required : bool
        One of them is required (False: the command checks, e.g. when another input needs none).

    Returns
    -------
    None
    """
    kind = parser.add_mutually_exclusive_group(required=required)
    kind.add_argument("--inner", type=_parse_inner, help="chessboard inner corners NXxNY, e.g. 9x6")
    if charuco:
        kind.add_argument("--charuco", type=_parse_squares, metavar="SXxSY",
                          help="a ChArUco board of SXxSY squares (needs --marker-m and --dictionary)")
    kind.add_argument("--target", metavar="FILE",
                      help="a Kalibr target YAML (target_type aprilgrid or checkerboard) instead")
    parser.add_argument("--square-m", type=float, help="square side, metres (with --inner, --charuco)")


def board_from_args(args) -> dict:
    """The board block of ``--inner``/``--square-m`` (a chessboard) or ``--target`` (Kalibr's file).

    ``--charuco`` is the calibrate command's own (``cvsflow.cli.calibrate``).

    Parameters
    ----------
    args : argparse.Namespace
        ``inner`` ((nx, ny) inner corners) and ``square_m`` (m), or ``target`` (a path).

    Returns
    -------
    board : dict
        ``squares_x``, ``squares_y``, ``square_m``; or the target file's board
        (:func:`cvsflow.io.targets.read_target_board`).

    Raises
    ------
    InputError
        ``--square-m`` missing with ``--inner`` or given with ``--target``; an unreadable file.
    ConfigError
        A target file of an unsupported type or with a missing or invalid key.
    """
    from cvsflow.exceptions import InputError

    if getattr(args, "target", None) is not None:
        if args.square_m is not None:
            raise InputError(f"--target {args.target}: the target file gives the board's size; "
                             "leave out --square-m")
        from cvsflow.io.targets import read_target_board

        return read_target_board(args.target)
    if args.square_m is None:
        raise InputError("--square-m: the square side in metres is needed with --inner or --charuco")
    nx, ny = args.inner
    return {"squares_x": nx + 1, "squares_y": ny + 1, "square_m": float(args.square_m)}
