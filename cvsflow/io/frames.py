"""Timestamped frame folders: a camera input beside video files.

Two layouts are read, both with exact timestamps (int64 ns):

- **ASL / EuRoC** (Kalibr, yac): a camera folder ``cam0/`` holding ``data.csv`` (``timestamp
  [ns],filename``, with or without a leading ``#``) and the images in ``data/``. The folder given
  may be ``cam0`` itself or the dataset folder holding one ``cam*`` folder. A csv that names
  ``.png`` where the file is ``.jpg`` (yac's) is read with the file that exists, under a WARNING.
- **Named by time**: a folder of images whose names are integer nanoseconds
  (``1606153907495166540.jpg``).

:func:`frame_list` gives the frames in time order; :func:`iter_frames_gray` yields ``(frame,
t_s, gray)`` as :func:`cvsflow.io.media.iter_video_gray` does, so the corners stage runs on a
folder unchanged (``functools.partial(iter_frames_gray, folder)`` is a frame source of
:func:`cvsflow.corners.extract_corners_parallel`). ``t_s`` is ``t_ns / 1e9`` (absolute, as a
pose stream's: use ``t_ns`` for arithmetic); :func:`add_frame_ns` puts the exact ``t_ns`` into a
corners table.

Bad input (:class:`~cvsflow.exceptions.FrameFolderError`, file or csv line named): a folder whose
images carry no timestamp (names that are not ns integers, no ``data.csv``), a csv row naming an
image that does not exist, a timestamp that is missing, not an integer or goes back, two frames
at one time, a folder without images, frames of two sizes. A ``data.csv`` cut short (its last
row cut mid-row, or images in ``data/`` no row names) is read as far as it goes with a WARNING.
An image that cannot be decoded or is cut short (a JPEG without its end marker, a PNG without
IEND) costs its frame: it is named in a WARNING and yielded as None (``undecodable=True``) or
left out. (Calibration stills are checked by Pillow's decoder instead,
:func:`cvsflow.io.media.read_gray`: a phone's still may carry data after its JPEG's end marker, a
motion photo its video, which the end-marker test would take for a cut file.)
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from cvsflow.exceptions import FrameFolderError
from cvsflow.io.media import IMAGE_SUFFIXES

log = logging.getLogger(__name__)

FRAME_COLUMNS = ["frame", "t_ns", "t_s", "path"]
_NS_NAME = re.compile(r"\d{16,}")  # 1e15 ns is 11.6 days: shorter integers are frame numbers


def _asl_camera_folder(folder: Path) -> Path | None:
    """The ASL camera folder (data.csv + data/) at or one level below ``folder``, or None."""
    if (folder / "data.csv").is_file():
        return folder
    cams = sorted(p for p in folder.glob("cam*") if (p / "data.csv").is_file())
    if len(cams) > 1:
        raise FrameFolderError(
            f"{folder}: {len(cams)} ASL camera folders ({', '.join(p.name for p in cams)}); "
            "expected one: give the camera folder itself (e.g. cam0)"
        )
    return cams[0] if cams else None


def _image_for(data: Path, name: str, csv: Path, lineno: int) -> Path:
    """The image a csv row names, or the one file of the same stem with another image suffix."""
    path = data / name
    if path.is_file():
        return path
    stem = Path(name).stem
    others = [data / (stem + s) for s in IMAGE_SUFFIXES if (data / (stem + s)).is_file()]
    if len(others) == 1:
        return others[0]
    several = f" (several files of that stem: {[p.name for p in others]})" if others else ""
    raise FrameFolderError(f"{csv}, line {lineno}: names {name!r}, which is not in {data}{several}; "
                           "expected every row's image in the data folder")  # fmt: skip


def _named_image_exists(data: Path, name: str) -> bool:
    """Whether ``data`` holds the image ``name`` or one of its stem with an image suffix."""
    stem = Path(name).stem
    return (data / name).is_file() or any((data / (stem + s)).is_file() for s in IMAGE_SUFFIXES)


def _read_asl_csv(cam: Path) -> pd.DataFrame:
    """Rows of an ASL camera folder's data.csv: t_ns, path (in file order), line."""
    csv, data = cam / "data.csv", cam / "data"
    if not data.is_dir():
        raise FrameFolderError(f"{cam}: {csv.name} but no data/ folder of images; expected the ASL layout "
                               "cam0/data.csv + cam0/data/")  # fmt: skip
    rows = []
    with open(csv, encoding="utf-8-sig", errors="replace") as fh:
        for lineno, raw in enumerate(fh, start=1):
            cells = [c.strip() for c in raw.strip().lstrip("#").split(",")]
            if not any(cells) or (lineno == 1 and not cells[0].lstrip("+").isdigit()):
                continue  # blank, or the header line
            cut = not raw.endswith("\n") and bool(rows)  # the file ends inside this row?
            if cut and (len(cells) < 2 or not _named_image_exists(data, cells[1])):
                log.warning("%s, line %d: the file ends inside this row (%r): cut short; the row is "
                            "left out", csv, lineno, raw.strip()[:60])  # fmt: skip
                break
            if len(cells) < 2 or not cells[0].lstrip("+").isdigit():
                raise FrameFolderError(
                    f"{csv}, line {lineno}: {raw.strip()[:60]!r}; expected 'timestamp [ns],filename' "
                    "with an integer time in nanoseconds"
                )
            rows.append((int(cells[0]), _image_for(data, cells[1], csv, lineno), lineno, cells[1]))
    if not rows:
        raise FrameFolderError(f"{csv}: no frame rows; expected 'timestamp [ns],filename' rows")
    out = pd.DataFrame(rows, columns=["t_ns", "path", "line", "named"])
    unnamed = sorted({p.name for p in data.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES}
                     - {p.name for p in out["path"]})
    if unnamed:  # a csv cut short at a row boundary says nothing else
        log.warning("%s: %d of the %d images in %s are named by no row (e.g. %s; the csv cut "
                    "short?); only the %d rows' frames are read", csv, len(unnamed),
                    len(unnamed) + len(out), data, unnamed[0], len(out))  # fmt: skip
    renamed = int(sum(p.name != n for p, n in zip(out["path"], out["named"], strict=True)))
    if renamed:
        log.warning("%s: %d of %d rows name a file that is not there under that name but is with "
                    "another suffix (e.g. %s for %s); read the file that exists", csv, renamed,
                    len(out), out["named"].iloc[0], out["path"].iloc[0].name)  # fmt: skip
    out.attrs["source"] = f"{csv}"
    out.attrs["n_renamed"] = renamed
    return out


def _read_named_by_time(folder: Path) -> pd.DataFrame:
    """Images of a folder named by integer nanoseconds: t_ns, path, line (0)."""
    images = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not images:
        raise FrameFolderError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)}) and no data.csv; expected "
                               "frames named by their time in ns, or an ASL camera folder")  # fmt: skip
    untimed = [p.name for p in images if not _NS_NAME.fullmatch(p.stem)]
    if untimed:
        raise FrameFolderError(
            f"{folder}: {len(untimed)} of {len(images)} images carry no timestamp in their name (e.g. "
            f"{untimed[0]!r}); expected names that are integer nanoseconds (1606153907495166540.png, "
            "16 digits or more) or an ASL data.csv (timestamp [ns],filename)"
        )
    out = pd.DataFrame({"t_ns": [int(p.stem) for p in images], "path": images, "line": 0})
    out = out.sort_values("t_ns", kind="stable").reset_index(drop=True)  # by value: names differ in length
    out.attrs["source"] = f"{folder} (file names)"
    return out


def frame_list(folder) -> pd.DataFrame:
    """The frames of a timestamped frame folder, in time order.

    Parameters
    ----------
    folder : str or Path
        An ASL camera folder (``data.csv`` + ``data/``), a dataset folder holding one ``cam*``
        folder, or a folder of images named by integer nanoseconds.

    Returns
    -------
    frames : DataFrame
        ``frame`` (int64, 0-based in time order), ``t_ns`` (int64, exact), ``t_s``
        (``t_ns / 1e9``), ``path`` (Path of the image); ``attrs``: ``layout`` (``asl`` or
        ``named_by_time``), ``source``, ``folder``.

    Raises
    ------
    FrameFolderError
        Not a folder; no timestamps (names not ns, no data.csv); a csv row naming a missing
        image or with a time that is not an integer; times that go back or repeat (lines or
        files named); no frames.
    """
    folder = Path(folder)
    if not folder.is_dir():
        what = "is a file" if folder.exists() else "not found"
        raise FrameFolderError(f"{folder}: {what}; expected a folder of timestamped frames (an ASL "
                               "cam0 folder or images named by ns)")  # fmt: skip
    cam = _asl_camera_folder(folder)
    rows = _read_asl_csv(cam) if cam is not None else _read_named_by_time(folder)
    t = rows["t_ns"].to_numpy(np.int64)
    names = [f"line {n}" for n in rows["line"]] if cam is not None else [p.name for p in rows["path"]]
    step = np.diff(t)
    if cam is not None and (step < 0).any():
        k = int(np.flatnonzero(step < 0)[0])
        raise FrameFolderError(f"{rows.attrs['source']}, {names[k + 1]}: time {t[k + 1]} ns is earlier than "
                               f"{names[k]}'s {t[k]} ns; expected the rows in time order")  # fmt: skip
    if (step == 0).any():
        k = int(np.flatnonzero(step == 0)[0])
        raise FrameFolderError(f"{rows.attrs['source']}: {names[k]} and {names[k + 1]} are both at "
                               f"{t[k]} ns; expected one frame per timestamp")  # fmt: skip
    out = pd.DataFrame({"frame": np.arange(len(rows), dtype=np.int64), "t_ns": t, "t_s": t / 1e9,
                        "path": list(rows["path"])})  # fmt: skip
    out.attrs = {"layout": "asl" if cam is not None else "named_by_time", "source": rows.attrs["source"],
                 "folder": str(cam if cam is not None else folder)}  # fmt: skip
    return out


def image_is_complete(path) -> bool:
    """Whether an image file ends as its format requires (JPEG's EOI marker, PNG's IEND chunk).

    ``cv2.imread`` decodes a JPEG cut short into a grey-filled image without an error; the
    end marker tells.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    bool
        False for a JPEG without FFD9 at its end (trailing zero padding allowed) or a PNG
        without IEND in its last bytes; True for other formats (left to the decoder).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".jpg", ".jpeg", ".png"):
        return True
    with open(path, "rb") as fh:
        fh.seek(0, 2)
        size = fh.tell()
        fh.seek(max(0, size - 4096))
        tail = fh.read()
    return data_is_complete(tail, "png" if suffix == ".png" else "jpeg")


def data_is_complete(tail: bytes, kind: str) -> bool:
    """Whether encoded image data ends as its format requires (a file's, or a bag message's).

    Parameters
    ----------
    tail : bytes
        The data's last bytes (at least its last 16; the whole data will do).
    kind : {"jpeg", "png"}
        Its format.

    Returns
    -------
    bool
        JPEG: ends with the EOI marker FFD9 (trailing zero padding allowed); PNG: the IEND
        chunk in the last 16 bytes.
    """
    if kind == "png":
        return b"IEND" in tail[-16:]
    return tail.rstrip(b"\x00").endswith(b"\xff\xd9")


def read_frame_gray(path) -> np.ndarray | None:
    """A frame as 8-bit grayscale, or None when it cannot be decoded or is cut short.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    ndarray of uint8, shape (H, W), or None
    """
    if not image_is_complete(path):
        return None
    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)


def iter_frames_gray(folder, start=0, stop=None, undecodable=False
                     ) -> Iterator[tuple[int, float, np.ndarray | None]]:  # fmt: skip
    """Yield ``(frame, t_s, gray)`` for the frames ``[start, stop)`` of a frame folder.

    The frame source interface of :func:`cvsflow.io.media.iter_video_gray`: frame k is the
    k-th frame in time order, ``t_s`` its time (``t_ns / 1e9``, absolute seconds).

    Parameters
    ----------
    folder : str or Path
        As :func:`frame_list`.
    start : int
        First frame index.
    stop : int, optional
        Index to stop before; default the last frame.
    undecodable : bool
        Also yield frames whose image cannot be decoded or is cut short, as ``(frame, t_s,
        None)``; False leaves them out. Either way they are named in one WARNING.

    Returns
    -------
    iterator of (int, float, ndarray or None)

    Raises
    ------
    FrameFolderError
        As :func:`frame_list`; a frame of another size than the folder's first (file and both
        sizes named); or not one frame of the folder decodes.
    """
    frames = frame_list(folder)
    size = _first_size(frames)  # every chunk checks against the folder's first frame
    bad = []
    n_ok = 0
    try:
        for frame, t_s, path in frames[["frame", "t_s", "path"]].iloc[start:stop].itertuples(index=False):
            gray = read_frame_gray(path)
            if gray is None:
                bad.append(Path(path).name)
                if undecodable:
                    yield int(frame), float(t_s), None
                continue
            if gray.shape != size:
                raise FrameFolderError(
                    f"{path}: frame {frame} is {gray.shape[1]}x{gray.shape[0]} px, the folder's first "
                    f"frame {size[1]}x{size[0]} px; expected every frame at one size (one camera, "
                    "one resolution)"
                )
            n_ok += 1
            yield int(frame), float(t_s), gray
    finally:
        if bad:
            log.warning("%s: %d frames cannot be decoded or are cut short (truncated?): %s", folder,
                        len(bad), ", ".join(bad[:10]) + (" ..." if len(bad) > 10 else ""))  # fmt: skip
    if bad and n_ok == 0 and start == 0 and stop is None:
        raise FrameFolderError(f"{folder}: not one of {len(bad)} frames decodes (the first: {bad[0]})")


def _first_size(frames: pd.DataFrame) -> tuple[int, int] | None:
    """(height, width) of the first frame that decodes, or None when none does."""
    for path in frames["path"]:
        gray = read_frame_gray(path)
        if gray is not None:
            return gray.shape
    return None


def frame_folder_info(folder) -> dict:
    """Frame count, rate and size of a frame folder (as :func:`cvsflow.io.media.video_info`).

    Parameters
    ----------
    folder : str or Path

    Returns
    -------
    dict
        ``n_frames``, ``fps`` (1 / the median interval, Hz; 0 for one frame), ``period_s``,
        ``width``, ``height`` (px, of the first frame that decodes), ``t0_ns``, ``t1_ns``,
        ``layout``.

    Raises
    ------
    FrameFolderError
        As :func:`frame_list`, or no frame decodes.
    """
    frames = frame_list(folder)
    t = frames["t_ns"].to_numpy(np.int64)
    period = float(np.median(np.diff(t))) / 1e9 if len(t) > 1 else 0.0
    for path in frames["path"]:
        gray = read_frame_gray(path)
        if gray is not None:
            break
    else:
        raise FrameFolderError(f"{folder}: not one of {len(frames)} frames decodes")
    return {"n_frames": len(frames), "fps": 1.0 / period if period > 0 else 0.0, "period_s": period,
            "width": int(gray.shape[1]), "height": int(gray.shape[0]), "t0_ns": int(t[0]),
            "t1_ns": int(t[-1]), "layout": frames.attrs["layout"]}  # fmt: skip


def add_frame_ns(corners: pd.DataFrame, frames: pd.DataFrame) -> pd.DataFrame:
    """A corners (or poses) table with the exact ``t_ns`` of each row's frame beside ``t_s``.

    Parameters
    ----------
    corners : DataFrame
        A table with a ``frame`` column (0-based indices of ``frames``) and ``t_s``.
    frames : DataFrame
        :func:`frame_list`.

    Returns
    -------
    DataFrame
        A copy with ``t_ns`` (int64) after ``t_s``; ``attrs`` kept.
    """
    out = corners.copy()
    t_ns = frames["t_ns"].to_numpy(np.int64)[out["frame"].to_numpy()]
    out.insert(out.columns.get_loc("t_s") + 1, "t_ns", t_ns)
    out.attrs = dict(corners.attrs)
    return out
