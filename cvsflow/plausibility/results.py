"""Plausibility of the optimisers' results: the focal lengths, mountings and time offset a
fit may return (rules optimise_se3 and optimise_seed), as :mod:`cvsflow.plausibility.checks` checks
each stage's inputs. A failed check raises a :class:`~cvsflow.exceptions.ResultRangeError` that
names the key, its value and the range (docs/failures.md).
"""

from __future__ import annotations

import numpy as np

from cvsflow.exceptions import ResultRangeError


def _check_focal(name, fx, fy, K_calib, factor, where):
    for axis, f, f0 in (("fx_px", fx, K_calib[0][0]), ("fy_px", fy, K_calib[1][1])):
        f = float(f)
        if not (np.isfinite(f) and f > 0 and f0 / factor <= f <= f0 * factor):
            raise ResultRangeError(
                f"{where}: {name} {axis} = {f:.6g} px is outside its physical range (expected "
                f"finite, positive and within a factor {factor:g} of the calibrated {f0:.6g} px, "
                f"i.e. {f0 / factor:.6g}..{f0 * factor:.6g} px); the pairs or the Vicon data are "
                "implausible (see the earlier stages' warnings)"
            )


def check_se3_result(result, K_calib, max_offset_s=30.0, where="se3 result", focal_factor=4.0,
                     max_mount_m=2.0):
    """se3 results inside physical ranges: focal lengths, both mountings, the time offset.

    Parameters
    ----------
    result : dict
        ``result.yaml`` content (``fx_px, fy_px, T_Cm_C, T_Bm_B, dt_offset_s``).
    K_calib : array_like, shape (3, 3)
        The calibrated camera matrix (camera.yaml), px.
    max_offset_s : float
        ``sync.max_offset_s``, s.
    focal_factor : float
        fx, fy within [f / factor, f * factor] of the calibrated values.
    max_mount_m : float
        Largest translation of T_Cm_C and T_Bm_B, metres.
    where : str
        Name of the result in the error messages.

    Returns
    -------
    warnings : list of str
        Always empty: a failed check raises (the list keeps the signature of the checks that
        also warn).

    Raises
    ------
    ResultRangeError
        A value out of range; the message names the key, its value and the range.
    """
    _check_focal("se3", result["fx_px"], result["fy_px"], K_calib, focal_factor, where)
    for key in ("T_Cm_C", "T_Bm_B"):
        if key not in result:
            continue
        T = np.asarray(result[key], dtype=float)
        d = float(np.linalg.norm(T[:3, 3]))
        if not (np.isfinite(T).all() and d <= max_mount_m):
            raise ResultRangeError(
                f"{where}: se3 {key} translation {d:.4g} m is outside its physical range "
                f"(expected finite and at most {max_mount_m:g} m: a marker mounting)"
            )
    dt = float(result.get("dt_offset_s", 0.0))
    if not (np.isfinite(dt) and abs(dt) <= max_offset_s):
        raise ResultRangeError(
            f"{where}: se3 dt_offset_s = {dt:.6g} s is outside +-{max_offset_s:g} s (sync.max_offset_s)"
        )
    return []


def check_seed_result(result, K_calib, where="seed result", focal_factor=4.0):
    """seed results inside physical ranges: finite positive focal lengths near the calibration.

    The chapter's method, applied as written, drifts to its grid bounds on sessions it was not
    built on (docs/methods.md); such a run is flagged ``diverged`` by the optimiser and reported as such,
    so its focal range is left to that flag. Non-finite values are an error either way.

    Parameters
    ----------
    result : dict
        seed ``result.yaml`` content: ``fx_px``, ``fy_px`` (px), optionally ``diverged``
        (bool) and ``P_bar`` (dict or list of the mean pose error per dimension, m and rad;
        every entry must be finite).
    K_calib : array_like, shape (3, 3)
        The calibrated camera matrix (camera.yaml), px.
    where : str
        Name of the result in the error messages.
    focal_factor : float
        fx, fy within [f / factor, f * factor] of the calibrated values (not applied when
        ``result["diverged"]``).

    Returns
    -------
    warnings : list of str
        Always empty: a failed check raises (the list keeps the signature of the checks that
        also warn).

    Raises
    ------
    ResultRangeError
        fx or fy not finite or not positive, or (unless ``result["diverged"]``) beyond
        ``focal_factor`` of the calibration.
    """
    factor = np.inf if result.get("diverged") else focal_factor
    _check_focal("seed", result["fx_px"], result["fy_px"], K_calib, factor, where)
    P_bar = result.get("P_bar")
    if P_bar is not None:
        vals = np.asarray(list(P_bar.values()) if isinstance(P_bar, dict) else P_bar, dtype=float)
        if not np.isfinite(vals).all():
            raise ResultRangeError(f"{where}: seed P_bar has non-finite entries {vals.tolist()}")
    return []
