"""The chapter's gesture synchronisation: the onset of a tilt from a still start (rule ``sync``).

``sync_gesture`` times the moment the board starts to tilt, in both streams, and takes the
difference as the offset (``t_vicon_s = t_video_s + dt_offset_s``).
"""

from __future__ import annotations

import numpy as np

from cvsflow.exceptions import SyncError
from cvsflow.geometry import mean_rotation, rotation_angle, sample_period
from cvsflow.plausibility import OVERLAP_FLOOR
from cvsflow.sync.streams import _cvs_rotations, _spans, _vicon_relative, check_take_covers_video


def _tilt_onset(t, R, valid, still_s, low_rad, high_rad):
    """Times at which the angle from the still start first crosses low (backtracked) and high."""
    idx = np.flatnonzero(valid)
    if idx.size < 3:
        return None
    t_ok = t[idx]
    start = idx[t_ok <= t_ok[0] + still_s]
    if start.size < 2:
        return None
    R_ref = mean_rotation(R[start])
    ang = np.full(len(t), np.nan)
    ang[idx] = rotation_angle(R_ref.T @ R[idx])
    above = np.flatnonzero(np.nan_to_num(ang, nan=0.0) > high_rad)
    if above.size == 0:
        return None
    k_high = int(above[0])
    below = np.flatnonzero(np.nan_to_num(ang[:k_high], nan=np.inf) < low_rad)
    if below.size == 0:
        return None
    k_low = int(below[-1])

    def crossing(k, level):  # linear crossing between samples k and the next valid one
        nxt = idx[idx > k]
        if nxt.size == 0:
            return t[k]
        k2 = int(nxt[0])
        a0, a1 = ang[k], ang[k2]
        f = 0.0 if a1 == a0 else np.clip((level - a0) / (a1 - a0), 0.0, 1.0)
        return t[k] + f * (t[k2] - t[k])

    prev_high = idx[idx < k_high]
    t_high = crossing(int(prev_high[-1]), high_rad) if prev_high.size else t[k_high]
    return crossing(k_low, low_rad), t_high


def sync_gesture(
    poses_raw,
    bodies,
    max_offset_s=30.0,
    min_quality=0.5,
    still_s=0.5,
    low_rad=np.radians(3.0),
    high_rad=np.radians(10.0),
    camera="camera",
    board="board",
):
    """The chapter's synchronisation: onsets of the forward-tilt gesture in both streams.

    Parameters
    ----------
    poses_raw, bodies : DataFrame
        As :func:`sync_angular_speed`.
    still_s : float
        Length of the still start used as reference attitude in each stream, s.
    low_rad, high_rad : float
        The gesture is the first time the board turns more than ``high_rad`` from its
        reference attitude; its onset is the last crossing of ``low_rad`` before that, rad.

    Returns
    -------
    sync : dict
        As :func:`sync_angular_speed`, ``method`` "gesture". ``dt_offset_s`` is the difference
        of the onsets (Vicon minus video).

    Raises
    ------
    SyncError
        No gesture found in a stream, offset beyond ``max_offset_s``, or quality below
        ``min_quality``.

    Notes
    -----
    Seed section 1.3, "Test Procedure". The angle from the reference attitude is the same in
    both streams (module docstring). Quality = exp(-|d| / h), with d the disagreement between
    the offsets given by the low and the high crossings and h the video frame interval: a
    clean gesture has the same shape in both streams, so both crossings agree.
    """
    video_span, take_span = _spans(poses_raw, bodies)
    check_take_covers_video(video_span, take_span, min_share=OVERLAP_FLOOR)
    t_c, R_c, valid_c = _cvs_rotations(poses_raw)
    t_v, T_v, valid_v = _vicon_relative(bodies, camera, board)
    R_v = np.where(valid_v[:, None, None], T_v[:, :3, :3], np.eye(3))
    on_c = _tilt_onset(t_c, R_c, valid_c, still_s, low_rad, high_rad)
    on_v = _tilt_onset(t_v, R_v, valid_v, still_s, low_rad, high_rad)
    for name, on in (("video", on_c), ("Vicon", on_v)):
        if on is None:
            raise SyncError(
                f"gesture sync: no forward tilt found in the {name} stream (expected a still "
                f"start of {still_s} s, then a rotation above {np.degrees(high_rad):.1f} deg)"
            )
    dt_low = on_v[0] - on_c[0]
    dt_high = on_v[1] - on_c[1]
    h = sample_period(t_c)
    quality = float(np.exp(-abs(dt_high - dt_low) / h))
    details = {
        "onset_video_s": float(on_c[0]),
        "onset_vicon_s": float(on_v[0]),
        "dt_low_s": float(dt_low),
        "dt_high_s": float(dt_high),
        "low_deg": float(np.degrees(low_rad)),
        "high_deg": float(np.degrees(high_rad)),
        "max_offset_s": float(max_offset_s),
        "min_quality": float(min_quality),
    }
    if abs(dt_low) > max_offset_s:
        raise SyncError(
            f"gesture sync: offset {dt_low:.3f} s beyond max_offset_s {max_offset_s} "
            f"(onsets: video {on_c[0]:.3f} s, Vicon {on_v[0]:.3f} s)"
        )
    if quality < min_quality:
        raise SyncError(
            f"gesture sync: quality {quality:.3f} below min_quality {min_quality} (onset offset "
            f"{dt_low:.4f} s, peak-crossing offset {dt_high:.4f} s disagree)"
        )
    return {"dt_offset_s": float(dt_low), "method": "gesture", "quality": quality, "details": details}
