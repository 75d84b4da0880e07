"""The rig fit as the workflow runs it: camera entries from each camera's tables, the result
named by camera, held-out scores and the fused poses' NEES against a known truth.

The fit is :func:`cvsflow.rig.fit.optimise_se3_rig`, its held-out folds
:func:`~cvsflow.rig.fit.cross_validate_se3_rig`; rules ``optimise_se3_rig`` and
``heldout_se3_rig`` (cvsflow/workflow/rules/rig.smk) read the files and call these.
"""

from __future__ import annotations

import numpy as np

from cvsflow.exceptions import OptimiseError
from cvsflow.geometry import transforms as tf

#: Options of the config's ``rig`` block passed on to ``optimise_se3_rig``.
RIG_FIT_OPTIONS = ("free", "fit_dt", "loss", "f_scale_px", "match_tol_s", "fused_calibration_cov",
                   "fused_max_residual_px")
#: Intrinsics a rig fit estimates when the config does not say: the mono se3 default of
#: config.yaml (cx, cy trade off with the mounting's rotation and stay at the calibration).
RIG_DEFAULT_FREE = ("fx", "fy", "k1", "k2", "p1", "p2")


def rig_camera_entries(corners, cameras, dt_offsets_s):
    """``optimise_se3_rig``'s camera entries from each camera's corners, camera.yaml and sync.

    Parameters
    ----------
    corners : sequence of DataFrame
        Each camera's corners.parquet (its own video clock), camera 0 first.
    cameras : sequence of dict
        Each camera's camera.yaml (``K``, ``dist``, ``std``).
    dt_offsets_s : sequence of float
        Each camera's starting offset (its sync.yaml ``dt_offset_s``), t_vicon = t_video + dt.

    Returns
    -------
    entries : list of dict
        ``{"corners", "camera", "dt_offset_s"}`` per camera.

    Raises
    ------
    OptimiseError
        The three sequences differ in length or are empty.
    """
    corners, cameras, dt_offsets_s = list(corners), list(cameras), list(dt_offsets_s)
    if not corners or not (len(corners) == len(cameras) == len(dt_offsets_s)):
        raise OptimiseError(
            f"se3 rig: {len(corners)} corner tables, {len(cameras)} cameras and "
            f"{len(dt_offsets_s)} offsets; expected one of each per camera (at least one)"
        )
    return [{"corners": c, "camera": k, "dt_offset_s": float(dt)}
            for c, k, dt in zip(corners, cameras, dt_offsets_s, strict=True)]  # fmt: skip


def rig_fit_options(rig_cfg):
    """The ``rig`` config block's options for ``optimise_se3_rig`` (``RIG_FIT_OPTIONS``).

    Parameters
    ----------
    rig_cfg : dict
        ``config["rig"]``.

    Returns
    -------
    options : dict
        The keys of ``RIG_FIT_OPTIONS`` it has, ``free`` as a tuple (``RIG_DEFAULT_FREE`` when
        absent); absent others are ``optimise_se3_rig``'s defaults.
    """
    out = {k: rig_cfg[k] for k in RIG_FIT_OPTIONS if k in rig_cfg}
    out["free"] = tuple(out.get("free", RIG_DEFAULT_FREE))
    return out


def name_rig_result(result, names, sessions=None):
    """The rig result with each camera's name, session and own estimates and standard errors.

    Parameters
    ----------
    result : dict
        ``optimise_se3_rig``'s ``result`` (parameters named ``cam{i}_...`` and ``T_Bm_B_...``).
    names : sequence of str
        Camera names, camera 0 first.
    sessions : sequence of str, optional
        Each camera's session (results/<session>/ of its camera.yaml and corners).

    Returns
    -------
    result : dict
        A copy; each ``cameras[i]`` gains ``name``, ``session`` (when given), ``estimates`` and
        ``std_errors`` (its own parameters, the ``cam{i}_`` prefix dropped: the mono se3
        result's names); the top level ``camera_names``, ``T_Bm_B_std_errors``; ``time_s``
        dropped (a wall time: the same inputs give the same file).

    Raises
    ------
    OptimiseError
        ``names`` does not give one name per camera.
    """
    cams = result["cameras"]
    if len(names) != len(cams):
        raise OptimiseError(f"se3 rig: {len(names)} camera names for {len(cams)} cameras")
    out = {k: v for k, v in result.items() if k != "time_s"}
    out["camera_names"] = [str(n) for n in names]
    est, se = result["estimates"], result["std_errors"]
    named = []
    for i, c in enumerate(cams):
        prefix = f"cam{i}_"
        c = dict(c, name=str(names[i]))
        if sessions is not None:
            c["session"] = str(sessions[i])
        c["estimates"] = {k[len(prefix):]: v for k, v in est.items() if k.startswith(prefix)}
        c["std_errors"] = {k[len(prefix):]: v for k, v in se.items() if k.startswith(prefix)}
        named.append(c)
    out["cameras"] = named
    out["T_Bm_B_std_errors"] = {k: v for k, v in se.items() if k.startswith("T_Bm_B_")}
    return out


def heldout_scores(heldout):
    """Held-out accuracy of the rig's fused poses against the Vicon reference, by cameras.

    Parameters
    ----------
    heldout : DataFrame
        ``cross_validate_se3_rig``'s table (``n_cameras``, ``err_dist_m``, ``err_angle_rad``).

    Returns
    -------
    scores : dict
        ``n_frames``, ``rms_dist_m``, ``rms_angle_rad``, and the same per number of cameras
        that saw the frame (``by_cameras``: {n: {...}}).
    """

    def rms(x):
        return float(np.sqrt(np.mean(np.asarray(x, float) ** 2)))

    def one(df):
        return {"n_frames": int(len(df)), "rms_dist_m": rms(df["err_dist_m"]),
                "rms_angle_rad": rms(df["err_angle_rad"])}

    out = one(heldout)
    out["by_cameras"] = {int(n): one(g) for n, g in heldout.groupby("n_cameras")}
    return out


def fused_pose_nees(poses, T_C0_B_true):
    """NEES of each fused board pose against its true pose (6 expected if the covariance is right).

    Parameters
    ----------
    poses : DataFrame
        :func:`~cvsflow.rig.poses.fused_rig_poses` rows (``cvs_x_m .. cvs_qw``
        and ``S00 .. S55``: the covariance of ``[dt (m), dtheta (rad)]`` in C0, rotation
        perturbed on the left).
    T_C0_B_true : ndarray, shape (N, 4, 4)
        The true board pose in camera 0 at each row's time, m.

    Returns
    -------
    nees : ndarray, shape (N,)
        ``d^T S^-1 d``, d = [t_est - t_true, log(R_est R_true^T)].
    """
    T_true = np.asarray(T_C0_B_true, float)
    q = poses[["cvs_qx", "cvs_qy", "cvs_qz", "cvs_qw"]].to_numpy(float)
    T_est = tf.make_T(tf.R_from_quat(q), poses[["cvs_x_m", "cvs_y_m", "cvs_z_m"]].to_numpy(float))
    d_r = tf.rvec_from_R(T_est[:, :3, :3] @ np.swapaxes(T_true[:, :3, :3], 1, 2)).reshape(-1, 3)
    d = np.concatenate([T_est[:, :3, 3] - T_true[:, :3, 3], d_r], axis=1)
    S = poses[[f"S{a}{b}" for a in range(6) for b in range(6)]].to_numpy(float).reshape(-1, 6, 6)
    return np.einsum("fi,fi->f", d, np.linalg.solve(S, d[:, :, None])[:, :, 0])
