"""Tests of cvsflow.corners.track's helpers (tracking itself: test_corners.py)."""

from __future__ import annotations

import cv2
import numpy as np


def test_shrunk_by_four_is_the_area_average_by_halvings():
    from cvsflow.corners.track import _shrunk

    rng = np.random.default_rng(4)
    gray = cv2.GaussianBlur(rng.integers(0, 256, (480, 640), dtype=np.uint8), (5, 5), 1.5)
    small = _shrunk(gray, 4)
    ref = cv2.resize(gray, None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA)
    assert small.shape == ref.shape
    assert np.abs(small.astype(int) - ref.astype(int)).max() <= 1
    assert _shrunk(gray, 4) is small  # cached for the flow out of this frame
