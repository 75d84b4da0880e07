"""Atomic writers and plain readers for YAML and Parquet.

A stage never leaves a half-written file: every writer goes to a temporary file in the
target folder and renames it into place, so a failure leaves the old state untouched.
"""

from __future__ import annotations

import contextlib
import io
import os
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from cvsflow.exceptions import InputError


@contextlib.contextmanager
def atomic_output(path, suffix=None):
    """Yield a temporary path beside ``path``; rename it onto ``path`` only on success.

    Parameters
    ----------
    path : str or Path
        The final output file; its parent directory is created.
    suffix : str, optional
        Suffix of the temporary file (writers that pick the format by suffix need it);
        default ``path``'s suffix, or ``.tmp``.

    Returns
    -------
    contextmanager of Path
        Yields the temporary path to write; on an exception it is deleted and ``path`` is left
        as it was (no partial output).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(
        prefix=f".{path.name}.", suffix=suffix or path.suffix or ".tmp", dir=path.parent
    )
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def refuse_overwrite(paths, force: bool = False, command: str = "cvsflow") -> None:
    """InputError naming the files of ``paths`` that exist, unless ``force``: a command that writes
    into a folder the user names never replaces their files of the same names in silence.

    Parameters
    ----------
    paths : iterable of str or Path
        Every file the command may write; checked before it computes anything.
    force : bool
        The command's ``--force``: replace them.
    command : str
        The command, for the message.

    Returns
    -------
    None

    Raises
    ------
    InputError
        Some of ``paths`` exist (all of them named) and ``force`` is False.
    """
    existing = [str(p) for p in paths if Path(p).exists()]
    if existing and not force:
        raise InputError(
            f"{command}: {', '.join(existing)} {'exists' if len(existing) == 1 else 'exist'}; it "
            "never overwrites a file: give another --out, or --force to replace "
            f"{'it' if len(existing) == 1 else 'them'}"
        )


def read_text_lines(path, kind="CSV") -> list[str]:
    """The lines of a UTF-8 text export (a BOM is dropped); InputError naming ``path`` when it is
    missing or not text (``kind`` names what was expected, e.g. "CSV", "TSV").

    Parameters
    ----------
    path : str or Path
        The text file.
    kind : str, default "CSV"
        What the file should be, for the error message.

    Returns
    -------
    list of str
        The lines without their line ends (CRLF or LF).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig", errors="strict")
    except FileNotFoundError as exc:
        raise InputError(f"{path}: file not found") from exc
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a text {kind} file ({exc})") from exc
    return text.splitlines()


def check_frames(path, frames, first, lines, column="Frame") -> None:
    """Frame numbers must be integers, one step apart; else InputError naming the line.

    Parameters
    ----------
    path : str or Path
        The file read, for the message.
    frames : ndarray of float, shape (N,)
        The frame column as read (NaN where the cell was empty).
    first : int
        0-based index in the file of the first data line (so data row i is line first + i + 1).
    lines : sequence of str
        The data lines, ``lines[i]`` holding ``frames[i]``, to quote the bad cell.
    column : str, default "Frame"
        Column name for the message.

    Returns
    -------
    None

    Raises
    ------
    InputError
        A non-integer or missing frame number, or a step other than 1 (gap, repeat, reorder).
    """
    bad = np.isnan(frames) | (frames != np.round(frames))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(
            f"{path}, line {first + i + 1}, column {column}: expected an integer frame number, "
            f"got {lines[i].split(',')[0].split(chr(9))[0]!r}"
        )
    steps = np.diff(frames)
    if np.any(steps != 1):
        i = int(np.flatnonzero(steps != 1)[0]) + 1
        raise InputError(
            f"{path}, line {first + i + 1}: frame {int(frames[i])} follows frame "
            f"{int(frames[i - 1])} (expected consecutive frames)"
        )


def drop_cut_last_row(lines, n_cols, sep=",") -> tuple[list[str], bool]:
    """The data lines without a last line cut mid-row (an export or copy interrupted).

    Parameters
    ----------
    lines : list of str
        The data lines (no header).
    n_cols : int
        Cells a whole line has at least.
    sep : str
        Cell separator.

    Returns
    -------
    lines : list of str
        ``lines``, less its last line when that one has fewer than ``n_cols`` cells.
    cut : bool
        Whether the last line was left out. A short line before the last stays, for
        :func:`parse_numeric_block` to name as an error.
    """
    if lines and lines[-1].count(sep) + 1 < n_cols:
        return lines[:-1], True
    return lines, False


def parse_numeric_block(
    path, lines, first, n_cols, column_names, sep=",", na_values=(), expected=None, pandas_na=False
) -> np.ndarray:
    """Parse data lines into a float array of shape (len(lines), n_cols); empty cells are NaN.

    Parameters
    ----------
    path : Path
        For messages.
    lines : list of str
        The data lines (no header).
    first : int
        0-based index in the file of ``lines[0]`` (messages give 1-based line numbers).
    n_cols : int
        Cells used per line; lines with fewer cells are an error (a cut file).
    column_names : list of str
        One name per used cell, for messages.
    sep : str
    na_values : sequence of str
        Extra cell texts meaning "not seen" (for example ``NaN`` or ``NULL``).
    expected : str, optional
        What the ``n_cols`` cells are, for the message about a short line (default: "as the
        header says").
    pandas_na : bool
        Also read pandas' default missing-value texts (``NaN``, ``NA``, ``null``, ...) as gaps.

    Returns
    -------
    values : ndarray, shape (len(lines), n_cols)

    Raises
    ------
    InputError
        A line with fewer than ``n_cols`` cells, or a non-numeric cell: file, 1-based line and
        column name.
    """
    if not lines:
        raise InputError(f"{path}, line {first + 1}: no data rows after the header")
    n_cells = np.fromiter((ln.count(sep) + 1 for ln in lines), int, len(lines))
    short = np.flatnonzero(n_cells < n_cols)
    if short.size:
        i = int(short[0])
        where = "the last row: file cut short" if i == len(lines) - 1 else "a truncated row"
        raise InputError(
            f"{path}, line {first + i + 1}: {n_cells[i]} cells, expected {n_cols} "
            f"{f'({expected})' if expected else 'as the header says'}; {where}"
        )
    # Bytes, not a StringIO: a StringIO of an ASCII block holds 4 bytes a character (a
    # 20-minute 300 Hz Vicon export: 87 MB of text took 350 MB more); the parser is the same.
    block = "\n".join(lines).encode("utf-8")
    na = ["", *na_values]
    try:
        return pd.read_csv(
            io.BytesIO(block), sep=sep, header=None, usecols=range(n_cols), dtype=np.float64,
            engine="c", skip_blank_lines=False, na_values=na, keep_default_na=pandas_na,
            encoding="utf-8",
        ).to_numpy()
    except (ValueError, TypeError):
        pass
    cells = pd.read_csv(
        io.BytesIO(block), sep=sep, header=None, usecols=range(n_cols), dtype=str,
        keep_default_na=pandas_na, skip_blank_lines=False, encoding="utf-8",
    ).to_numpy()
    for i, row in enumerate(cells):
        for j, cell in enumerate(row):
            if not isinstance(cell, str):
                continue  # a gap text pandas read as NaN
            cell = cell.strip()
            if cell == "" or cell in na:
                continue
            try:
                float(cell)
            except ValueError:
                raise InputError(
                    f"{path}, line {first + i + 1}, column {column_names[j]}: non-numeric cell "
                    f"{cell!r} (expected a number, or an empty cell for a gap)"
                ) from None
    raise InputError(f"{path}, lines {first + 1}-{first + len(lines)}: unreadable data block")


def _to_builtin(obj):
    """Numpy scalars and arrays to plain Python, so YAML stays readable and portable."""
    if isinstance(obj, dict):
        return {str(k): _to_builtin(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_to_builtin(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _to_builtin(obj.tolist())
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_yaml(data, path):
    """Write a mapping as YAML, atomically. Numpy values become plain lists and floats.

    Parameters
    ----------
    data : dict
        The mapping; key order is kept.
    path : str or Path
        Output file.

    Returns
    -------
    None
    """
    with atomic_output(path) as tmp, open(tmp, "w") as fh:
        yaml.safe_dump(_to_builtin(data), fh, sort_keys=False, default_flow_style=None)


def read_yaml(path):
    """Read a YAML mapping; a missing or malformed file is an InputError naming it.

    Parameters
    ----------
    path : str or Path
        The YAML file.

    Returns
    -------
    dict
        The top-level mapping (anything else is an InputError).
    """
    path = Path(path)
    try:
        with open(path) as fh:
            data = yaml.safe_load(fh)
    except FileNotFoundError as exc:
        raise InputError(f"{path}: file not found") from exc
    except yaml.YAMLError as exc:
        # PyYAML's own message spans lines with a drawing of the spot: one line here
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        what = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise InputError(f"{path}: not valid YAML{where} ({what})") from exc
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a YAML mapping, got {type(data).__name__}")
    return data


def write_parquet(df: pd.DataFrame, path):
    """Write a DataFrame as Parquet (no index), atomically.

    Parameters
    ----------
    df : DataFrame
        The table.
    path : str or Path
        Output file.

    Returns
    -------
    None
    """
    with atomic_output(path) as tmp:
        df.to_parquet(tmp, index=False)


def read_parquet(path, columns=None) -> pd.DataFrame:
    """Read a Parquet table; a missing file is an InputError naming it.

    Parameters
    ----------
    path : str or Path
        The Parquet file.
    columns : list of str, optional
        Read only these columns; default all.

    Returns
    -------
    DataFrame
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: file not found")
    return pd.read_parquet(path, columns=columns)


def read_csv_table(path, columns=()) -> pd.DataFrame:
    """Read a CSV table with a header; a missing file or column is an InputError naming it.

    Parameters
    ----------
    path : str or Path
        The CSV file.
    columns : sequence of str
        Columns the caller needs.

    Returns
    -------
    DataFrame
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    table = pd.read_csv(path)
    missing = [c for c in columns if c not in table.columns]
    if missing:
        raise InputError(f"{path}: missing columns {missing}")
    if table.empty:
        raise InputError(f"{path}: no rows")
    return table


def draw_figure(output, name: str, make) -> bool:
    """Draw and save a job's figure when its rule declares it (the config's ``figures``).

    Parameters
    ----------
    output : snakemake.io.Namedlist or mapping
        The job's outputs; with ``figures: false`` its rule declares no figure.
    name : str
        The figure's output name.
    make : callable
        Called without arguments, returns the matplotlib Figure; not called when the figure is
        not an output.

    Returns
    -------
    bool
        Whether the figure was drawn.
    """
    path = output.get(name)
    if not path:
        return False
    save_figure(make(), path)
    return True


def save_figure(fig, path, dpi: int = 120) -> None:
    """Save a matplotlib Figure atomically and release its memory.

    A figure with constrained layout is saved at its own size; any other is cropped to its
    drawn content (``bbox_inches="tight"``).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure; closed afterwards.
    path : str or Path
        Output file; its suffix picks the format (default png).
    dpi : int, default 120
        Resolution of raster formats.

    Returns
    -------
    None
    """
    import matplotlib.pyplot as plt
    from matplotlib.layout_engine import ConstrainedLayoutEngine

    # constrained layout already fits everything inside the figure; "tight" would draw the
    # figure once more only to find its bounding box (about a tenth of an analyse job's CPU)
    constrained = isinstance(fig.get_layout_engine(), ConstrainedLayoutEngine)
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=dpi, bbox_inches=None if constrained else "tight",
                    format=Path(path).suffix.lstrip(".") or "png")
    plt.close(fig)


def image_data_uri(path) -> str:
    """An image file as a ``data:`` URI, to embed it in a self-contained HTML page.

    Parameters
    ----------
    path : str or Path
        A PNG, JPEG or SVG file.

    Returns
    -------
    str
        ``data:<mime>;base64,<the file's bytes>``.
    """
    import base64
    import mimetypes

    mime = mimetypes.guess_type(str(path))[0] or "application/octet-stream"
    return f"data:{mime};base64,{base64.b64encode(Path(path).read_bytes()).decode('ascii')}"
