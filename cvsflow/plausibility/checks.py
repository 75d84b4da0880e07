"""Plausibility checks at the stage boundaries: plain functions on numpy/pandas data.

Each check either returns a list of warnings (str; the run can go on, and the stage puts them
in its YAML under ``warnings`` so that the report's summary can show them) or raises a named
:class:`~cvsflow.exceptions.ImplausibleError` whose message says where (the file, the body, the
frame), what is wrong, and what was expected. ``source`` arguments are only names for the
messages (usually the file the data came from); no check reads or writes files.

The optimisers' results are checked in :mod:`cvsflow.plausibility.results`. The failure modes
these checks catch are listed in ``docs/failures.md``.
"""

from __future__ import annotations

import logging

import numpy as np

from cvsflow.exceptions import (
    BoardNotSeenError,
    ImageSizeError,
    NoUsableRowsError,
    OverlapError,
    ScaleMismatchError,
    StaticBoardError,
    UnitsError,
)
from cvsflow.geometry import R_from_rvec, mean_rotation, rotation_angle

log = logging.getLogger(__name__)

#: below this share of video frames inside the Vicon take, pairs and sync stop (hard floor)
OVERLAP_FLOOR = 0.2
#: fewest overlapping frames with which sync and pairs still go on
MIN_OVERLAP_FRAMES = 30
#: What :func:`check_overlap`'s messages call the camera's samples (``frames``, counted in
#: ``unit``) and the motion capture (``take``, ``take_short``, its ``clock``) by default.
VIDEO_NAMES = {"frames": "video frames", "unit": "frames", "take": "Vicon take", "take_short": "take",
               "clock": "Vicon clock"}  # fmt: skip


def _span_m(P):
    """Largest distance between any two of the points P (M, 3), metres (NaN rows ignored)."""
    P = P[np.isfinite(P).all(axis=1)]
    if len(P) < 2:
        return np.nan
    d = P[:, None, :] - P[None, :, :]
    return float(np.sqrt((d**2).sum(axis=2)).max())


def _rms_radius_m(P):
    """RMS distance of the points P (M, 3) from their centroid, metres."""
    P = np.asarray(P, dtype=float)
    return float(np.sqrt(((P - P.mean(axis=0)) ** 2).sum(axis=1).mean()))


_UNIT_HINTS = {
    3: "the export's units row likely says m where the values are mm",
    2: "the export's units row likely says m where the values are cm",
    1: "the export's units row likely says cm where the values are mm",
    -1: "the export's units row likely says mm where the values are cm",
    -2: "the export's units row likely says cm where the values are m",
    -3: "the export's units row likely says mm where the values are m",
}


def _unit_hint(ratio):
    k = int(np.round(np.log10(ratio))) if np.isfinite(ratio) and ratio > 0 else 0
    if k in _UNIT_HINTS and abs(np.log10(ratio) - k) < 0.3:
        return _UNIT_HINTS[k]
    return "check the body's layout_m in the config and the units row of the export"


# --------------------------------------------------------------------------- Vicon


def check_marker_scale(markers, body_specs, source="markers", max_ratio=3.0):
    """Compare each body's marker cloud with its configured layout: same size, or a units error.

    Parameters
    ----------
    markers : DataFrame
        Wide marker table (``{name}_{x,y,z}_m``, metres, W).
    body_specs : dict
        ``{body: {"names": [...], "layout_m": (M, 3) or None}}``; bodies without a layout are
        skipped (a learned layout has the data's scale by construction).
    source : str
        Name of the data in messages (the Vicon export).
    max_ratio : float
        The median span of the observed markers (largest marker-to-marker distance in a
        frame where all are seen) may differ from the layout's span by this factor at most.

    Returns
    -------
    warnings : list of str
        Empty; a body whose markers are never seen together is skipped with a warning.

    Raises
    ------
    UnitsError
        Spans differ by more than ``max_ratio``; the message names the body, both spans and
        the likely cause (a ratio near 1000 is m read for mm, near 10 cm for mm, ...).
    """
    warnings = []
    for body, spec in body_specs.items():
        layout = spec.get("layout_m")
        if layout is None:
            continue
        names = list(spec["names"])
        cols = [[f"{n}_{a}_m" for a in "xyz"] for n in names]
        if any(c not in markers.columns for cc in cols for c in cc):
            continue
        Q = np.stack([markers[c].to_numpy(float) for c in cols], axis=1)  # (N, M, 3)
        seen = np.isfinite(Q).all(axis=(1, 2))
        if not seen.any():
            warnings.append(f"{source}: body {body!r}: its markers are never all seen at once; "
                            "marker scale not checked")
            continue
        Qs = Q[seen][:: max(1, int(seen.sum()) // 500)]
        d = Qs[:, :, None, :] - Qs[:, None, :, :]
        span_data = float(np.median(np.sqrt((d**2).sum(axis=3)).max(axis=(1, 2))))
        span_layout = _span_m(np.asarray(layout, dtype=float))
        ratio = span_data / span_layout if span_layout > 0 else np.inf
        if not (1.0 / max_ratio <= ratio <= max_ratio):
            raise UnitsError(
                f"{source}: body {body!r}: the markers {names} span {span_data:.4g} m (median "
                f"over {int(seen.sum())} frames), the configured layout_m spans {span_layout:.4g} m "
                f"(ratio {ratio:.4g}, expected within a factor {max_ratio:g}): {_unit_hint(ratio)}"
            )
    return warnings


def check_body_fits(bodies, body_specs, source="bodies", max_fit_rms_m=0.01, max_fit_rms_share=0.1,
                    max_bad_share=0.05):
    """Rigid-body fit residuals against the layout's scale and the marker noise.

    Parameters
    ----------
    bodies : DataFrame
        ``bodies.parquet`` table (``body``, ``valid``, ``fit_rms_m``).
    body_specs : dict
        ``{body: {"names": [...], "layout_m": (M, 3) or None}}`` (resolved layouts, or None).
    source : str
        Name of the marker data in messages.
    max_fit_rms_m : float
        ``vicon.max_fit_rms_m``: absolute residual limit, metres (marker noise is ~0.3 mm,
        placement errors a few mm).
    max_fit_rms_share : float
        ``vicon.max_fit_rms_share``: limit as a share of the layout's RMS radius. A sample is
        implausible when its residual exceeds the larger of the two limits.
    max_bad_share : float
        Above this share of implausible valid samples a warning is returned.

    Returns
    -------
    warnings : list of str

    Raises
    ------
    NoUsableRowsError
        A body with no valid sample.
    UnitsError
        The median residual over the valid samples exceeds the limit (the markers do not have
        the layout's shape or scale); the message names the body, both numbers and the cause.
    """
    warnings = []
    for body in sorted(set(bodies["body"])):
        sub = bodies[bodies["body"] == body]
        valid = sub["valid"].to_numpy(bool)
        if not valid.any():
            raise NoUsableRowsError(
                f"{source}: body {body!r} has no valid pose in any of its {len(sub)} samples "
                "(expected at least three non-collinear markers seen in some frames)"
            )
        spec = body_specs.get(body, {})
        layout = spec.get("layout_m")
        r_layout = _rms_radius_m(layout) if layout is not None else np.nan
        limit = max(max_fit_rms_m, max_fit_rms_share * r_layout) if np.isfinite(r_layout) else max_fit_rms_m
        rms = sub["fit_rms_m"].to_numpy(float)[valid]
        med = float(np.median(rms))
        if not med <= limit:
            ratio = np.nan
            if np.isfinite(r_layout) and r_layout > 0:
                ratio = (med + r_layout) / r_layout
            raise UnitsError(
                f"{source}: body {body!r}: rigid-body fit RMS {med:.4g} m (median of {valid.sum()} "
                f"valid samples), expected at most {limit:.4g} m (the larger of {max_fit_rms_m:g} m "
                f"and {max_fit_rms_share:g} x the layout's RMS radius {r_layout:.4g} m): the markers "
                f"do not have the layout's shape or scale; {_unit_hint(ratio)}"
            )
        bad = float(np.mean(rms > limit))
        if bad > max_bad_share:
            warnings.append(
                f"{source}: body {body!r}: {100 * bad:.1f} % of the valid samples have a fit RMS "
                f"above {limit:.4g} m (a marker swap or a bumped marker?)"
            )
    return warnings


# --------------------------------------------------------------------------- video poses


def check_poses_found(poses, corners=None, source="poses", corners_source="corners.parquet",
                      min_valid_share=0.2):
    """A poses table with zero valid frames is an error naming the video and the corners.

    Parameters
    ----------
    poses : DataFrame
        ``poses_raw.parquet`` table (``frame``, ``valid``).
    corners : DataFrame, optional
        ``corners.parquet`` (``frame``, ``found``), to count the frames with a board.
    source : str
        The video's name in messages.
    corners_source : str
        The corners file's name in messages.
    min_valid_share : float
        Below this share of valid frames a warning is returned.

    Returns
    -------
    warnings : list of str

    Raises
    ------
    BoardNotSeenError
        No frame with a valid pose.
    """
    n = len(poses)
    n_valid = int(poses["valid"].to_numpy(bool).sum()) if n else 0
    n_found = None
    if corners is not None and len(corners):
        n_found = int(corners.loc[corners["found"].to_numpy(bool), "frame"].nunique())
    found = "" if n_found is None else f"; the board was found in {n_found} of them ({corners_source})"
    if n_valid == 0:
        raise BoardNotSeenError(
            f"{source}: 0 of {n} video frames have a board pose{found}: expected the "
            "chessboard in view (is the video black, or the board size in the config wrong?)"
        )
    if n and n_valid / n < min_valid_share:
        return [f"{source}: only {n_valid} of {n} video frames ({100 * n_valid / n:.1f} %) have a "
                f"board pose{found}"]
    return []


# --------------------------------------------------------------------------- sync


def _valid_rotations(poses):
    p = poses.sort_values("frame", kind="stable")
    rvec = p[["rvec_0", "rvec_1", "rvec_2"]].to_numpy(float)
    valid = p["valid"].to_numpy(bool) & np.isfinite(rvec).all(axis=1)
    R = R_from_rvec(np.where(valid[:, None], rvec, 0.0))
    return p["t_s"].to_numpy(float), R, valid


def check_sync_inputs(poses, bodies, method="angular_speed", source_poses="poses_raw.parquet",
                      source_bodies="bodies.parquet", min_frames=10, min_motion_deg_s=3.0,
                      min_turn_deg=5.0):
    """Before synchronising: the board was seen, both bodies were tracked, and the board moved.

    Parameters
    ----------
    poses : DataFrame
        ``poses_raw`` (``frame, t_s, valid, rvec_0..2``).
    bodies : DataFrame
        Native-rate bodies table (``body``, ``valid``).
    method : str
        ``sync.method``; the motion check applies to ``angular_speed``.
    source_poses, source_bodies : str
        Names of the two tables in the error messages.
    min_frames : int
        Fewest video frames with a pose.
    min_motion_deg_s, min_turn_deg : float
        The board moved when the 95th percentile of its angular speed between consecutive
        valid frames reaches ``min_motion_deg_s`` (deg/s) and it turned by at least
        ``min_turn_deg`` (deg) from its median attitude over the take.

    Returns
    -------
    warnings : list of str
        Always empty: a failed check raises (the list keeps the signature of the checks that
        also warn).

    Raises
    ------
    BoardNotSeenError
        Fewer than ``min_frames`` frames with a board pose.
    NoUsableRowsError
        A Vicon body with fewer than ``min_frames`` valid samples.
    StaticBoardError
        The board did not move (angular-speed sync needs motion).
    """
    t, R, valid = _valid_rotations(poses)
    n_valid = int(valid.sum())
    if n_valid < min_frames:
        raise BoardNotSeenError(
            f"{source_poses}: the board was found in {n_valid} of {len(poses)} video frames "
            f"(expected at least {min_frames}): nothing to synchronise"
        )
    for body in sorted(set(bodies["body"])):
        nv = int(bodies.loc[bodies["body"] == body, "valid"].to_numpy(bool).sum())
        if nv < min_frames:
            raise NoUsableRowsError(
                f"{source_bodies}: body {body!r} is valid in {nv} samples (expected at least "
                f"{min_frames}): nothing to synchronise"
            )
    if method != "angular_speed":
        return []
    pair = valid[:-1] & valid[1:]
    speed = np.degrees(rotation_angle(np.swapaxes(R[:-1][pair], 1, 2) @ R[1:][pair]) / np.diff(t)[pair])
    p95 = float(np.percentile(speed, 95)) if speed.size else 0.0
    Rv = R[valid]
    R_med = mean_rotation(Rv)
    turn = float(np.degrees(np.percentile(rotation_angle(R_med.T @ Rv), 99)))
    if p95 < min_motion_deg_s or turn < min_turn_deg:
        raise StaticBoardError(
            f"{source_poses}: the board moved by at most {p95:.2f} deg/s (95th percentile over "
            f"{n_valid} frames with a pose; it turned by at most {turn:.2f} deg) over the take: "
            f"angular-speed sync needs motion (expected at least {min_motion_deg_s:g} deg/s and "
            f"{min_turn_deg:g} deg; use sync.method: gesture, or move the board)"
        )
    return []


def overlap_share(t_video_s, dt_offset_s, take_span_s):
    """Share of video frames whose Vicon time t + dt lies inside the take [t0, t1].

    Parameters
    ----------
    t_video_s : array_like, shape (N,)
        Video frame times, video clock, s.
    dt_offset_s : float
        t_vicon_s = t_video_s + dt_offset_s, s.
    take_span_s : (float, float)
        First and last Vicon sample times (inclusive), s.

    Returns
    -------
    share : float
        Share of the frames inside the take, 0..1; 0.0 for no frames. A NaN time counts as
        outside.
    """
    t = np.asarray(t_video_s, dtype=float) + dt_offset_s
    if t.size == 0:
        return 0.0
    return float(np.mean((t >= take_span_s[0]) & (t <= take_span_s[1])))


def check_overlap(t_video_s, dt_offset_s, take_span_s, min_share=0.8, floor=OVERLAP_FLOOR,
                  min_frames=MIN_OVERLAP_FRAMES, source="video and Vicon take", names=None):
    """The share of video frames inside the Vicon take: a warning under ``min_share``, an error
    under ``floor`` or ``min_frames``.

    Parameters
    ----------
    t_video_s : ndarray, shape (N,)
        Video frame times, video clock, s.
    dt_offset_s : float
        t_vicon_s = t_video_s + dt_offset_s, s.
    take_span_s : (float, float)
        First and last Vicon sample times, s.
    min_share : float
        ``sync.min_overlap_share``.
    names : dict, optional
        What the messages call the streams (:data:`VIDEO_NAMES`' keys ``frames``, ``unit``,
        ``take``, ``take_short``, ``clock``); default the video's and the Vicon take's
        (:func:`camera_pose_names` for a camera-pose stream).

    Returns
    -------
    share : float
        Share of video frames inside the take (0..1).
    warnings : list of str

    Raises
    ------
    OverlapError
        Share below ``floor`` or fewer than ``min_frames`` frames inside.
    """
    n = {**VIDEO_NAMES, **(names or {})}
    t = np.asarray(t_video_s, dtype=float)
    share = overlap_share(t, dt_offset_s, take_span_s)
    n_in = int(round(share * len(t)))
    span = (
        f"{n['frames']} span {t.min():.3f}..{t.max():.3f} s, i.e. {t.min() + dt_offset_s:.3f}.."
        f"{t.max() + dt_offset_s:.3f} s on the {n['clock']} (dt_offset_s = {dt_offset_s:.4f}), the "
        f"{n['take_short']} spans {take_span_s[0]:.3f}..{take_span_s[1]:.3f} s"
    ) if t.size else f"no {n['frames']}"
    if share < floor or n_in < min_frames:
        raise OverlapError(
            f"{source}: only {n_in} of {len(t)} {n['frames']} ({100 * share:.1f} %) fall inside the "
            f"{n['take']} (expected at least {100 * floor:.0f} % and {min_frames} {n['unit']}): {span}"
        )
    if share < min_share:
        return share, [
            f"{source}: only {100 * share:.1f} % of the {n['frames']} fall inside the {n['take']} "
            f"(sync.min_overlap_share {min_share:g}); the rest are left out: {span}"
        ]
    return share, []


def camera_pose_names(file) -> dict:
    """What :func:`check_overlap`'s messages call a camera-pose stream and its motion capture.

    Parameters
    ----------
    file : str or Path
        The camera-pose stream file, as the session names it.

    Returns
    -------
    dict
        ``frames``, ``unit``, ``take``, ``take_short``, ``clock`` (:data:`VIDEO_NAMES`' keys).
    """
    return {"frames": f"camera poses of {file}", "unit": "poses", "take": "motion capture",
            "take_short": "motion capture", "clock": "motion-capture clock"}  # fmt: skip


# --------------------------------------------------------------------------- pairs


def check_pair_distances(pairs, source="pairs", max_gap_m=1.0, max_ratio=3.0):
    """Camera-to-board distance from the Vicon (|t_Cm_Bm|) against PnP's (|t_C_B|).

    The two differ by at most the mounting offsets (camera optics to its markers, board
    origin to its markers: a few tens of centimetres). A ratio of 1000 is a units error, a
    ratio of 2 a wrong ``square_m`` or a wrong focal length.

    Parameters
    ----------
    pairs : DataFrame
        ``pairs.parquet`` (``cmbm_{x,y,z}_m``, ``cvs_{x,y,z}_m``).
    max_gap_m : float
        Largest plausible difference of the medians, metres.
    max_ratio : float
        Largest plausible ratio of the medians; an error needs both limits exceeded.
    source : str
        Name of the table in the error messages.

    Returns
    -------
    warnings : list of str
        Always empty: a failed check raises (the list keeps the signature of the checks that
        also warn).

    Raises
    ------
    NoUsableRowsError
        An empty pairs table.
    ScaleMismatchError
        Medians differ by more than ``max_gap_m`` and by a factor above ``max_ratio``.
    """
    if len(pairs) == 0:
        raise NoUsableRowsError(f"{source}: 0 pairs")

    def median_norm(prefix):
        xyz = pairs[[f"{prefix}_{a}_m" for a in "xyz"]].to_numpy(float)
        return float(np.median(np.linalg.norm(xyz, axis=1)))

    d_vic, d_cvs = median_norm("cmbm"), median_norm("cvs")
    ratio = d_vic / d_cvs if d_cvs > 0 else np.inf
    if abs(d_vic - d_cvs) > max_gap_m and not (1.0 / max_ratio <= ratio <= max_ratio):
        raise ScaleMismatchError(
            f"{source}: median camera-to-board distance {d_vic:.4g} m from the Vicon (|t_Cm_Bm|) "
            f"but {d_cvs:.4g} m from PnP (|t_C_B|), ratio {ratio:.4g}; expected them within "
            f"{max_gap_m:g} m (the mounting offsets): {_unit_hint(ratio)}, or board.square_m is wrong"
        )
    return []


def check_rows(table, source, what="rows"):
    """A table with zero rows is an error naming it (a stage never succeeds on nothing).

    Parameters
    ----------
    table : DataFrame or sized
        The table (anything with ``len``).
    source : str
        Its name (file or stage) in the error message.
    what : str
        What a row is, in the error message (``"rows"``, ``"pairs"``, ...).

    Returns
    -------
    warnings : list of str
        Always empty: a failed check raises (the list keeps the signature of the checks that
        also warn).

    Raises
    ------
    NoUsableRowsError
    """
    if len(table) == 0:
        raise NoUsableRowsError(f"{source}: 0 {what} (expected at least one); see the earlier stages' logs")
    return []


def check_image_size(camera, width, height, camera_source="camera.yaml", video_source="video",
                     rotation_deg=0.0):
    """The video's frames must be the size the camera's intrinsics were calibrated at.

    Intrinsics do not carry over between image sizes: a phone's or webcam's video mode crops
    and scales the sensor, so stills at another resolution (or the same stills turned a
    quarter) give a camera matrix that is wrong for the video, and every pose from it wrong
    with no error of its own.

    Parameters
    ----------
    camera : dict
        camera.yaml content; ``width`` and ``height`` (px) are compared when present.
    width, height : int
        The video's frames as read (display rotation applied), px.
    camera_source, video_source : str
        Names for the message.
    rotation_deg : float
        The video's display rotation (for the message).

    Returns
    -------
    None

    Raises
    ------
    ImageSizeError
        The sizes differ; the message says whether they are a quarter turn apart.
    """
    if "width" not in camera or "height" not in camera:
        return
    cw, ch = int(camera["width"]), int(camera["height"])
    if (cw, ch) == (int(width), int(height)):
        return
    where = f"{video_source}: frames are {int(width)}x{int(height)} px"
    if rotation_deg:
        where += (f" (stored on their side, display rotation {rotation_deg:g} deg, turned upright as "
                  "players show them)")
    if (cw, ch) == (int(height), int(width)):
        hint = ("the stills are the frames turned a quarter: take the stills and the video with the camera "
                "held the same way up (a still's EXIF orientation and a video's display rotation are both "
                "applied)")
    else:
        hint = ("intrinsics do not carry over between resolutions (a video mode crops and scales the "
                "sensor): calibrate on stills at the video's resolution, for example frames taken from "
                "the video itself")
    raise ImageSizeError(f"{where}, but {camera_source} was calibrated on {cw}x{ch} px stills; {hint}")
