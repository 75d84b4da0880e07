"""Files of a rendered demo session (``data/{session}/``), written all-or-nothing.

Everything goes into a hidden temporary sibling folder, which is renamed onto the session
folder only when the whole session has been written; a failure leaves no partial output.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

import cv2

from cvsflow.errors import ConfigError, InputError
from cvsflow.io.files import write_parquet, write_yaml
from cvsflow.io.vicon import write_nexus_csv

SESSION_FILES = (
    "calib",
    "video.mp4",
    "vicon.csv",
    "truth.yaml",
    "truth_frames.parquet",
    "truth_corners.parquet",
)


@contextlib.contextmanager
def staged_session_dir(out_dir):
    """Yield a temporary folder beside ``out_dir``; on success it replaces ``out_dir``.

    An existing ``out_dir`` may only hold files a previous render wrote (``SESSION_FILES``,
    and Snakemake's ``.snakemake_timestamp``), so that a mistyped path never deletes a
    user's own recordings.

    Raises
    ------
    ConfigError
        ``out_dir`` exists and holds other files.
    """
    out_dir = Path(out_dir)
    if out_dir.exists():
        foreign = sorted(
            p.name
            for p in out_dir.iterdir()
            if p.name not in SESSION_FILES and not p.name.startswith(".snakemake")
        )
        if foreign:
            raise ConfigError(
                f"{out_dir}: holds files the synthetic renderer did not write ({foreign[:5]}); "
                "expected an empty or previously rendered session folder"
            )
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.render-", dir=out_dir.parent))
    # mkdtemp makes a private folder; the session folder is ordinary data.
    umask = os.umask(0)
    os.umask(umask)
    tmp.chmod(0o777 & ~umask)
    try:
        yield tmp
        if out_dir.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.old-", dir=out_dir.parent))
            out_dir.rename(old / out_dir.name)
            tmp.rename(out_dir)
            shutil.rmtree(old, ignore_errors=True)
        else:
            tmp.rename(out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def write_still(folder, name, image):
    """Write one calibration still (uint8 grey, lossless PNG) as ``folder/calib/name``."""
    path = Path(folder) / "calib" / name
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), image):
        raise InputError(f"{path}: could not be written as an image")


class VideoSink:
    """MPEG-4 part 2 (fourcc mp4v) writer of grey frames with a lossy quality setting.

    OpenCV's FFmpeg back end ignores a quality setting for mp4v, so each frame first makes a
    JPEG round trip at ``quality`` (0..100): blocky, ringing DCT artefacts like a webcam's.
    """

    def __init__(self, path, fps, size, quality):
        self.path = Path(path)
        self.quality = int(quality)
        self.n_frames = 0
        self._writer = cv2.VideoWriter(
            str(self.path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), tuple(size), True
        )
        if not self._writer.isOpened():
            raise InputError(f"{self.path}: cannot open an mp4v video writer")

    def write(self, grey):
        """Append one frame, uint8 shape (height, width)."""
        ok, buf = cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_QUALITY, self.quality])
        if not ok:
            raise InputError(f"{self.path}: frame {self.n_frames} could not be encoded")
        lossy = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
        self._writer.write(cv2.cvtColor(lossy, cv2.COLOR_GRAY2BGR))
        self.n_frames += 1

    def close(self):
        self._writer.release()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def write_session_tables(folder, vicon_df, vicon_rate_hz, truth, truth_frames, truth_corners):
    """Write ``vicon.csv`` (Nexus format), ``truth.yaml`` and the two truth Parquet tables."""
    folder = Path(folder)
    write_nexus_csv(vicon_df, folder / "vicon.csv", rate_hz=vicon_rate_hz)
    write_yaml(truth, folder / "truth.yaml")
    write_parquet(truth_frames, folder / "truth_frames.parquet")
    write_parquet(truth_corners, folder / "truth_corners.parquet")

