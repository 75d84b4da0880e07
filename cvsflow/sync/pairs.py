"""Per-frame pose pairs: each video frame's CVS pose beside the Vicon poses (rule ``pairs``).

Convention (docs/contracts.md): ``t_vicon_s = t_video_s + dt_offset_s``, the offset from
:mod:`cvsflow.sync.offset`. Inputs are ``poses_raw`` (per video frame: ``frame, t_s, valid,
rvec_0..2`` = rvec_C_B, ``x_m, y_m, z_m`` = tvec_C_B) and the bodies tables of
:mod:`cvsflow.mocap.bodies` (block-averaged 30 Hz, or native rate to interpolate).
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from cvsflow.exceptions import InputError, NoUsableRowsError
from cvsflow.geometry import (
    R_from_rvec,
    interpolate_T,
    invert_T,
    make_T,
    pose6_from_T,
    quat_from_R,
    sample_period,
    wrap_angle,
)
from cvsflow.mocap import body_poses
from cvsflow.plausibility import check_overlap

log = logging.getLogger(__name__)


def _pose_columns(prefix, T):
    q = quat_from_R(T[:, :3, :3])
    return {
        f"{prefix}_x_m": T[:, 0, 3],
        f"{prefix}_y_m": T[:, 1, 3],
        f"{prefix}_z_m": T[:, 2, 3],
        f"{prefix}_qx": q[:, 0],
        f"{prefix}_qy": q[:, 1],
        f"{prefix}_qz": q[:, 2],
        f"{prefix}_qw": q[:, 3],
    }


def build_pairs(poses_raw, bodies, dt_offset_s, mode="block", camera="camera", board="board",
                min_overlap_share=0.8):
    """Per video frame, the CVS pose and the Vicon poses side by side (``pairs.parquet``).

    Parameters
    ----------
    poses_raw : DataFrame
        ``poses_raw.parquet`` (video clock).
    bodies : DataFrame
        ``mode="block"``: the block-averaged ``bodies_30hz`` table; ``mode="interp"``: the
        native-rate ``bodies`` table, interpolated (SLERP) at each frame's exact Vicon time.
    dt_offset_s : float
        t_vicon_s = t_video_s + dt_offset_s, s.
    mode : {"block", "interp"}
        ``block``: the block nearest in time to the frame's Vicon time. Blocks are
        ``factor / rate`` apart (33.3 ms at 300 Hz / 10), so the block time and the frame's
        Vicon time differ by at most half of that, 16.7 ms, and on average a quarter.

    Returns
    -------
    pairs : DataFrame
        Schema of docs/contracts.md: ``frame, t_s, t_vicon_s``; ``cvs_*`` (T_C_B, metres,
        radians, and ``cvs_rvec_0..2``); ``vic_*``: the chapter's P* = P_b* - P_c* (seed eq.
        1.5), the 6-vector difference [x, y, z, roll, pitch, yaw] of T_W_Bm and T_W_Cm with
        angles wrapped to (-pi, pi]; ``cmbm_*`` T_Cm_Bm = inv(T_W_Cm) T_W_Bm; ``wcm_*``
        T_W_Cm; ``wbm_*`` T_W_Bm (position in metres, scalar-last quaternion). Only frames with
        a valid CVS pose and both Vicon poses valid.

        Only frames inside the take are used (a partial overlap): ``attrs["overlap_share"]``
        is the share of video frames inside it, ``attrs["warnings"]`` a warning under
        ``min_overlap_share``.

    Raises
    ------
    OverlapError
        Under 20 % (or 30 frames) of the video frames' Vicon times inside the take (both spans
        named).
    NoUsableRowsError
        No frame with both a CVS pose and valid Vicon poses (the counts of each named).
    InputError
        Unknown mode.
    """
    p = poses_raw.sort_values("frame", kind="stable").reset_index(drop=True)
    t_video = p["t_s"].to_numpy(float)
    t_vic = t_video + dt_offset_s
    t_b, T_W_Cm_all, v_c = body_poses(bodies, camera)
    _, T_W_Bm_all, v_b = body_poses(bodies, board)
    if mode == "block":
        half = 0.5 * sample_period(t_b, default=0.0)
        span = (t_b[0] - half, t_b[-1] + half)
        share, warnings = check_overlap(t_video, dt_offset_s, span, min_share=min_overlap_share,
                                        source="pairs")
        k = np.clip(np.searchsorted(t_b, t_vic), 1, len(t_b) - 1)
        k = np.where(np.abs(t_vic - t_b[k - 1]) <= np.abs(t_b[k] - t_vic), k - 1, k)
        T_W_Cm, T_W_Bm = T_W_Cm_all[k], T_W_Bm_all[k]
        inside = (t_vic >= span[0]) & (t_vic <= span[1])
        ok_v = v_c[k] & v_b[k] & inside
    elif mode == "interp":
        share, warnings = check_overlap(t_video, dt_offset_s, (t_b[0], t_b[-1]),
                                        min_share=min_overlap_share, source="pairs")
        T_W_Cm, ok_c, _ = interpolate_T(t_b, T_W_Cm_all, v_c, t_vic)
        T_W_Bm, ok_b, _ = interpolate_T(t_b, T_W_Bm_all, v_b, t_vic)
        ok_v = ok_c & ok_b
    else:
        raise InputError(f"build_pairs: mode {mode!r}, expected 'block' or 'interp'")
    rvec_cols = ["rvec_0", "rvec_1", "rvec_2"]
    tvec_cols = ["x_m", "y_m", "z_m"]
    ok_cvs = p["valid"].to_numpy(bool) & np.isfinite(p[rvec_cols + tvec_cols].to_numpy(float)).all(axis=1)
    keep = ok_cvs & ok_v
    if not keep.any():
        raise NoUsableRowsError(
            f"pairs: 0 of {len(keep)} video frames have both a CVS pose and valid Vicon poses "
            f"({int(ok_cvs.sum())} frames with a CVS pose in poses_raw, {int(ok_v.sum())} with both "
            f"Vicon bodies valid at t_video + {dt_offset_s:.4f} s in the bodies table); expected "
            "at least one frame with both"
        )
    for w in warnings:
        log.warning(w)
    p = p[keep]
    T_W_Cm, T_W_Bm = T_W_Cm[keep], T_W_Bm[keep]
    rvec = p[rvec_cols].to_numpy(float, copy=True)
    T_C_B = make_T(R_from_rvec(rvec), p[tvec_cols].to_numpy(float))
    cvs6 = pose6_from_T(T_C_B)
    P_star = pose6_from_T(T_W_Bm) - pose6_from_T(T_W_Cm)  # seed eq. 1.5
    P_star[:, 3:] = wrap_angle(P_star[:, 3:])
    T_Cm_Bm = invert_T(T_W_Cm) @ T_W_Bm
    names6 = ["x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad"]
    cols = {
        "frame": p["frame"].to_numpy(np.int64),
        "t_s": p["t_s"].to_numpy(float),
        "t_vicon_s": t_vic[keep],
    }
    cols.update({f"cvs_{n}": cvs6[:, i] for i, n in enumerate(names6)})
    cols.update({f"cvs_rvec_{i}": rvec[:, i] for i in range(3)})
    cols.update({f"vic_{n}": P_star[:, i] for i, n in enumerate(names6)})
    cols.update(_pose_columns("cmbm", T_Cm_Bm))
    cols.update(_pose_columns("wcm", T_W_Cm))
    cols.update(_pose_columns("wbm", T_W_Bm))
    n_drop_cvs = int((~ok_cvs).sum())
    n_drop_vic = int((ok_cvs & ~ok_v).sum())
    if n_drop_cvs or n_drop_vic:
        log.warning(
            "pairs: %d of %d frames kept (%d without a CVS pose, %d without valid Vicon poses)",
            int(keep.sum()),
            len(keep),
            n_drop_cvs,
            n_drop_vic,
        )
    out = pd.DataFrame(cols)
    out.attrs["overlap_share"] = share
    out.attrs["warnings"] = warnings
    return out


def make_pairs(poses_raw, bodies, bodies_30hz, dt_offset_s, resample="block", camera="camera", board="board",
               min_overlap_share=0.8):
    """The pairs stage: :func:`build_pairs` on the table that ``vicon.resample`` calls for.

    Parameters
    ----------
    poses_raw : DataFrame
        ``poses_raw.parquet`` (video clock).
    bodies : DataFrame
        Native-rate bodies table; used for ``resample="interp"`` (SLERP at each frame's exact
        Vicon time, no second interpolation through a 30 Hz grid).
    bodies_30hz : DataFrame
        Block-averaged table; used for ``resample="block"`` (nearest block, at most half a
        block, 16.7 ms at 300 Hz / 10, from the frame's Vicon time).
    dt_offset_s : float
        From sync.yaml: t_vicon_s = t_video_s + dt_offset_s, s.
    resample : {"block", "interp"}

    Returns
    -------
    pairs : DataFrame
        ``pairs.parquet`` (see :func:`build_pairs`).
    """
    table = bodies_30hz if resample == "block" else bodies
    return build_pairs(poses_raw, table, dt_offset_s, mode=resample, camera=camera, board=board,
                       min_overlap_share=min_overlap_share)
