"""Calibration stills and video frames."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from cvsflow.errors import InputError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def list_stills(folder) -> list[Path]:
    """Image files of a calibration folder, sorted by name."""
    folder = Path(folder)
    if folder.is_file():
        raise InputError(f"{folder}: is a file, expected a folder of stills (calib_dir)")
    if not folder.is_dir():
        raise InputError(f"{folder}: calibration folder not found")
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def read_gray(path) -> np.ndarray:
    """An image as 8-bit grayscale; an unreadable file is an InputError naming it."""
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise InputError(f"{path}: cannot be read as an image")
    return img


def open_video(path) -> cv2.VideoCapture:
    """Open a video or raise an InputError naming it."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a video file (video)")
    if not path.is_file():
        raise InputError(f"{path}: video file not found")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise InputError(f"{path}: cannot be opened as a video")
    return cap


def video_info(path) -> dict:
    """Frame count (as the container states it), rate (Hz) and size of a video."""
    cap = open_video(path)
    try:
        info = {
            "n_frames": int(cap.get(cv2.CAP_PROP_FRAME_COUNT)),
            "fps": float(cap.get(cv2.CAP_PROP_FPS)),
            "width": int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
            "height": int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)),
        }
    finally:
        cap.release()
    if info["width"] <= 0 or info["height"] <= 0:
        raise InputError(f"{path}: video has no frames")
    return info


def iter_video_gray(path, start=0, stop=None) -> Iterator[tuple[int, float, np.ndarray]]:
    """Yield (frame index, time in s from the container, grayscale image) for frames [start, stop).

    Times come from the container's presentation timestamps; where the container gives none
    (timestamp 0 after the first frame), frame index / fps is used.
    """
    cap = open_video(path)
    fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
    try:
        if start:
            _seek(cap, path, start)
        index = start
        while stop is None or index < stop:
            ok, frame = cap.read()
            if not ok:
                break
            t_s = cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
            if index > 0 and t_s <= 0.0:
                t_s = index / fps
            gray = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
            yield index, t_s, gray
            index += 1
    finally:
        cap.release()


def _seek(cap: cv2.VideoCapture, path, start: int) -> None:
    """Put ``cap`` before frame ``start``: a seek where the backend reports it exact, else
    reading frames from the start (some codecs and containers seek only to key frames). A
    video shorter than ``start`` frames is left at its end."""
    if cap.set(cv2.CAP_PROP_POS_FRAMES, start) and int(cap.get(cv2.CAP_PROP_POS_FRAMES)) == start:
        return
    cap.open(str(path))
    for _ in range(start):
        if not cap.grab():
            return
