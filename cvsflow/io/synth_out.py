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

from cvsflow.exceptions import ConfigError, InputError
from cvsflow.io.files import write_parquet, write_yaml
from cvsflow.io.mocap.vicon import write_nexus_csv

SESSION_FILES = (
    "calib",
    "video.mp4",
    "vicon.csv",
    "truth.yaml",
    "truth_frames.parquet",
    "truth_corners.parquet",
)
#: Files of one camera of a rendered rig (``data/{rig}/{camera}/``): the session's but the
#: Vicon export (the rig's, one folder up), plus the shared-view stills.
RIG_CAMERA_FILES = tuple(f for f in SESSION_FILES if f != "vicon.csv") + ("shared",)


@contextlib.contextmanager
def staged_session_dir(out_dir, allowed=SESSION_FILES):
    """Yield a temporary folder beside ``out_dir``; on success it replaces ``out_dir``.

    An existing ``out_dir`` may only hold files a previous render wrote (``SESSION_FILES``,
    and Snakemake's ``.snakemake_timestamp``), so that a mistyped path never deletes a
    user's own recordings.

    Parameters
    ----------
    out_dir : str or Path
        The session folder to (re)write, ``data/{session}``.
    allowed : tuple of str
        Names a previous render may have left in ``out_dir`` (default ``SESSION_FILES``;
        ``RIG_CAMERA_FILES`` for a rig camera's folder).

    Returns
    -------
    contextmanager of Path
        Yields the temporary folder to write into; on success it is renamed onto ``out_dir``
        (the old one removed), on an exception it is deleted and ``out_dir`` is left as it was.

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
            if p.name not in allowed and not p.name.startswith(".snakemake")
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


def write_still(folder, name, image, subdir="calib"):
    """Write one calibration still (uint8 grey, lossless PNG) as ``folder/subdir/name``.

    Parameters
    ----------
    folder : str or Path
        The (staged) session folder.
    name : str
        File name, e.g. ``calib_000.png``; its suffix picks the format.
    image : ndarray of uint8, shape (H, W)
        The still.
    subdir : str
        Sub-folder of ``folder``: ``calib`` (the camera's own stills) or ``shared`` (a rig's
        shared views).

    Returns
    -------
    None

    Raises
    ------
    InputError
        OpenCV could not write the file.
    """
    path = Path(folder) / subdir / name
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
    """Write ``vicon.csv`` (Nexus format), ``truth.yaml`` and the two truth Parquet tables.

    Parameters
    ----------
    folder : str or Path
        The (staged) session folder.
    vicon_df : DataFrame
        Wide marker table of both bodies' markers (metres in W, NaN gaps), written in mm.
    vicon_rate_hz : float
        Motion-capture rate, Hz.
    truth : dict
        The ``truth.yaml`` mapping (docs/contracts.md).
    truth_frames : DataFrame
        ``truth_frames.parquet``: true T_C_B per video frame.
    truth_corners : DataFrame
        ``truth_corners.parquet``: ``frame, corner, u_px, v_px`` true distorted corners.

    Returns
    -------
    None
    """
    folder = Path(folder)
    write_nexus_csv(vicon_df, folder / "vicon.csv", rate_hz=vicon_rate_hz)
    write_yaml(truth, folder / "truth.yaml")
    write_parquet(truth_frames, folder / "truth_frames.parquet")
    write_parquet(truth_corners, folder / "truth_corners.parquet")



class PyAvVideoSink:
    """Video writer through PyAV (FFmpeg): H.264, HEVC, MPEG-4 part 2 or Motion JPEG in MP4.

    Every frame carries its own presentation timestamp in units of ``1 / pts_rate_hz`` s, so
    variable frame rates (jittered timestamps, dropped frames) are stored exactly. No B-frames,
    so the decoded order is the presentation order and the first frame is at its own pts.

    Parameters
    ----------
    path : str or Path
    codec : {"h264", "hevc", "mp4v", "mjpeg"}
    size : tuple of int
        (width, height), px.
    fps : float
        Nominal rate, Hz (the container's average-rate hint).
    crf : int
        Constant rate factor of h264/hevc (0 lossless .. 51 worst).
    quality : int
        1..100 for mp4v and mjpeg (mapped to the FFmpeg quantiser 31..2).
    pts_rate_hz : int
        Ticks per second of the stream time base.
    """

    _ENCODERS = {"h264": "libx264", "hevc": "libx265", "mp4v": "mpeg4", "mjpeg": "mjpeg"}

    def __init__(self, path, codec, size, fps, crf=23, quality=75, pts_rate_hz=30000):
        from fractions import Fraction

        import av  # PyAV: the only writer here that does H.264/HEVC and per-frame timestamps

        self.path = Path(path)
        self.n_frames = 0
        self._av = av
        try:
            self._container = av.open(str(self.path), mode="w", format="mp4")
            rate = Fraction(fps).limit_denominator(1001)
            stream = self._container.add_stream(self._ENCODERS[codec], rate=rate)
        except (av.FFmpegError, KeyError, ValueError) as exc:
            raise InputError(f"{self.path}: cannot open a {codec} video writer ({exc})") from exc
        stream.width, stream.height = int(size[0]), int(size[1])
        stream.time_base = Fraction(1, int(pts_rate_hz))
        stream.codec_context.time_base = Fraction(1, int(pts_rate_hz))
        q = str(int(round(2 + (100 - int(quality)) / 99 * 29)))
        if codec == "h264":
            stream.pix_fmt = "yuv420p"
            stream.options = {"crf": str(int(crf)), "preset": "veryfast", "bf": "0"}
        elif codec == "hevc":
            stream.pix_fmt = "yuv420p"
            stream.options = {"crf": str(int(crf)), "preset": "veryfast",
                              "x265-params": "bframes=0:log-level=error"}
        elif codec == "mjpeg":
            stream.pix_fmt = "yuvj420p"
            stream.options = {"qmin": q, "qmax": q}
        else:
            stream.pix_fmt = "yuv420p"
            stream.options = {"qmin": q, "qmax": q, "bf": "0"}
        self._stream = stream
        self._last_pts = None

    def write(self, image, pts):
        """Append one frame (uint8 (H, W) grey or (H, W, 3) BGR) at integer timestamp ``pts``."""
        pts = int(pts)
        if self._last_pts is not None and pts <= self._last_pts:
            raise InputError(
                f"{self.path}: frame {self.n_frames} has pts {pts}, expected > {self._last_pts}"
            )
        fmt = "gray" if image.ndim == 2 else "bgr24"
        frame = self._av.VideoFrame.from_ndarray(image, format=fmt)
        frame.pts = pts
        frame.time_base = self._stream.time_base
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        self._last_pts = pts
        self.n_frames += 1

    def close(self):
        for packet in self._stream.encode(None):
            self._container.mux(packet)
        self._container.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
