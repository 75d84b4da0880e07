"""``cvsflow export camera`` and ``cvsflow export trajectory``: a finished run's camera and trajectories."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cvsflow.exceptions import InputError


def _camera_yaml_path(src) -> Path:
    src = Path(src)
    path = src / "camera.yaml" if src.is_dir() else src
    if not path.is_file():
        raise InputError(f"{path}: camera.yaml not found (give a results/<session> folder or the file)")
    return path


def cmd_export_camera(args) -> int:
    """``cvsflow export camera``: a camera.yaml as OpenCV, Kalibr or ROS file.

    Parameters
    ----------
    args : argparse.Namespace
        ``src`` (a results/<session> folder or a camera.yaml), ``format`` (opencv, kalibr,
        ros), ``out`` (output file), ``force`` (replace ``out`` if it exists).

    Returns
    -------
    int
        Exit code, 0 (errors are raised as :class:`CvsflowError` and reported by :func:`main`).

    Raises
    ------
    InputError
        No camera.yaml at ``src``, or a malformed one; ``out`` exists and no ``--force``.
    """
    from cvsflow.io.camera_formats import write_camera_format
    from cvsflow.io.files import read_yaml, refuse_overwrite

    refuse_overwrite([args.out], args.force, "cvsflow export camera")
    path = _camera_yaml_path(args.src)
    write_camera_format(read_yaml(path), args.format, args.out)
    print(f"wrote {args.out} ({args.format}) from {path}")
    return 0


def _trajectory_table(t_s, T):
    """Trajectory table (``t_s``, ``x_m..z_m``, ``qx..qw``, validity) of (N, 4, 4) transforms."""
    import pandas as pd

    from cvsflow.geometry import quat_from_R

    ok = np.isfinite(T).all(axis=(1, 2))
    q = np.full((len(T), 4), np.nan)
    q[ok] = quat_from_R(T[ok, :3, :3]).reshape(-1, 4)
    d = pd.DataFrame({"t_s": np.asarray(t_s, dtype=float)})
    for k, a in enumerate("xyz"):
        d[f"{a}_m"] = T[:, k, 3]
    for k, a in enumerate(("qx", "qy", "qz", "qw")):
        d[a] = q[:, k]
    d["pos_valid"] = d["rot_valid"] = ok
    return d


#: The trajectories ``cvsflow export trajectory`` writes of a session (``vicon_T_C_B`` only with
#: an se3 result).
TRAJECTORY_NAMES = ("cvs_T_C_B", "vicon_T_Cm_Bm", "vicon_T_C_B")
#: A flight's trajectories (results/flights/<flight>/*.tum), rewritten by ``export trajectory``.
FLIGHT_TRAJECTORIES = ("reference_aligned", "onboard_aligned", "onboard_unaligned")
#: evo's name of each trajectory format.
EVO_FORMAT = {"tum": "tum", "asl": "euroc", "kitti": "kitti"}


def session_trajectories(pairs, se3_result=None):
    """The unaligned trajectories of a session, as (N, 4, 4) transforms on the video clock.

    Parameters
    ----------
    pairs : DataFrame
        pairs.parquet (``t_s``, ``cvs_rvec_*``, ``cvs_{x,y,z}_m``, ``cmbm_*``).
    se3_result : dict, optional
        The se3 result.yaml: its mountings ``T_Cm_C`` and ``T_Bm_B`` map the Vicon pose into
        the camera optical and board frames.

    Returns
    -------
    dict
        ``cvs_T_C_B`` (PnP), ``vicon_T_Cm_Bm`` (Vicon, marker bodies) and with ``se3_result``
        ``vicon_T_C_B`` = T_Cm_C⁻¹ T_Cm_Bm T_Bm_B: the Vicon reference in the frames of the CVS
        estimate, so that ``evo_ape tum vicon_T_C_B.tum cvs_T_C_B.tum`` compares like with like.
    """
    from cvsflow.geometry import R_from_quat, R_from_rvec, invert_T, make_T

    rvec = pairs[["cvs_rvec_0", "cvs_rvec_1", "cvs_rvec_2"]].to_numpy(float)
    T_C_B = make_T(R_from_rvec(rvec), pairs[["cvs_x_m", "cvs_y_m", "cvs_z_m"]].to_numpy(float))
    q = pairs[[f"cmbm_q{a}" for a in "xyzw"]].to_numpy(float)
    T_Cm_Bm = make_T(R_from_quat(q), pairs[["cmbm_x_m", "cmbm_y_m", "cmbm_z_m"]].to_numpy(float))
    out = {"cvs_T_C_B": T_C_B.reshape(-1, 4, 4), "vicon_T_Cm_Bm": T_Cm_Bm.reshape(-1, 4, 4)}
    if se3_result is not None:
        T_C_Cm = invert_T(np.asarray(se3_result["T_Cm_C"], dtype=float))
        T_Bm_B = np.asarray(se3_result["T_Bm_B"], dtype=float)
        out["vicon_T_C_B"] = T_C_Cm @ out["vicon_T_Cm_Bm"] @ T_Bm_B
    return out


def _flight_tables(folder: Path) -> dict:
    """The aligned and unaligned trajectories of a finished flight, times exact."""
    from cvsflow.io.trajectory import read_trajectory

    return {name: read_trajectory(folder / f"{name}.tum", "tum") for name in FLIGHT_TRAJECTORIES}


def _session_tables(src: Path, se3_arg) -> tuple[dict, str]:
    """The unaligned trajectories of a session (from pairs.parquet) and what to tell about them."""
    from cvsflow.io.files import read_parquet, read_yaml

    path = src / "pairs.parquet" if src.is_dir() else src
    if not path.is_file():
        raise InputError(f"{path}: pairs.parquet not found (give a finished results/<session> folder, "
                         "or a results/flights/<flight> folder)")  # fmt: skip
    pairs = read_parquet(path)
    need = {"t_s", "cvs_rvec_0", "cvs_rvec_1", "cvs_rvec_2", "cvs_x_m", "cvs_y_m", "cvs_z_m",
            "cmbm_x_m", "cmbm_y_m", "cmbm_z_m", "cmbm_qx", "cmbm_qy", "cmbm_qz", "cmbm_qw"}
    if not need <= set(pairs.columns):
        missing = sorted(need - set(pairs.columns))
        raise InputError(f"{path}: missing columns {missing} (docs/contracts.md, pairs.parquet)")
    se3_path = Path(se3_arg) if se3_arg else path.parent / "se3" / "calib" / "result.yaml"
    if se3_arg and not se3_path.is_file():
        raise InputError(f"{se3_path}: se3 result.yaml not found")
    se3 = read_yaml(se3_path) if se3_path.is_file() else None
    if se3 is not None and not {"T_Cm_C", "T_Bm_B"} <= set(se3):
        raise InputError(f"{se3_path}: expected the keys T_Cm_C and T_Bm_B (an se3 result.yaml)")
    t_s = pairs["t_s"].to_numpy(float)
    tables = {name: _trajectory_table(t_s, T) for name, T in session_trajectories(pairs, se3).items()}
    note = (f"no {se3_path}: vicon_T_C_B (the Vicon in the CVS frames) not written; the two files "
            "differ by T_Cm_C and T_Bm_B, which evo's one-sided -a cannot remove" if se3 is None
            else f"mountings from {se3_path}")  # fmt: skip
    return tables, note


def cmd_export_trajectory(args) -> int:
    """``cvsflow export trajectory``: a session's or a flight's trajectories as TUM, ASL or KITTI files.

    A session (``results/<session>``): ``cvs_T_C_B`` (PnP), ``vicon_T_Cm_Bm`` and, when an se3
    result.yaml is found, ``vicon_T_C_B`` (see :func:`session_trajectories`): video clock (s), m,
    unaligned. A flight (``results/flights/<flight>``): its ``reference_aligned``,
    ``onboard_aligned`` and ``onboard_unaligned`` trajectories, read exactly and rewritten.

    Parameters
    ----------
    args : argparse.Namespace
        ``results`` (a results/<session> folder or its pairs.parquet, or a flight's folder),
        ``out_dir``, ``se3`` (a result.yaml, or None for ``RESULTS/se3/calib/result.yaml`` when
        present), ``format`` (``tum``, ``asl``, ``kitti``: :mod:`cvsflow.io.trajectory`),
        ``force`` (replace files of the names it writes in ``out_dir``).

    Returns
    -------
    int
        Exit code, 0 (errors are raised as :class:`CvsflowError` and reported by :func:`main`).

    Raises
    ------
    InputError
        No pairs.parquet (nor a flight's trajectories), missing pairs columns, a given ``se3``
        file missing, or one without ``T_Cm_C`` and ``T_Bm_B``; a flight file that cannot be read;
        a file of a name it writes in ``out_dir`` and no ``--force`` (checked first).
    """
    from cvsflow.io.files import refuse_overwrite
    from cvsflow.io.trajectory import SUFFIX, kitti_times_path, write_trajectory

    src = Path(args.results)
    fmt = getattr(args, "format", "tum") or "tum"
    out = Path(args.out_dir)
    flight = src.is_dir() and (src / f"{FLIGHT_TRAJECTORIES[0]}.tum").is_file()
    paths = [out / f"{n}{SUFFIX[fmt]}" for n in (FLIGHT_TRAJECTORIES if flight else TRAJECTORY_NAMES)]
    if fmt == "kitti":
        paths += [kitti_times_path(p) for p in paths]
    refuse_overwrite(paths, getattr(args, "force", False), "cvsflow export trajectory")
    if flight:
        tables, note = _flight_tables(src), f"the flight's trajectories of {src}, rewritten exactly"
        ref, est = "reference_aligned", "onboard_unaligned"
    else:
        tables, note = _session_tables(src, args.se3)
        ref, est = ("vicon_T_C_B" if "vicon_T_C_B" in tables else "vicon_T_Cm_Bm"), "cvs_T_C_B"
    written = []
    for name, table in tables.items():
        path = out / f"{name}{SUFFIX[fmt]}"
        write_trajectory(table, path, fmt)
        written += [path] + ([kitti_times_path(path)] if fmt == "kitti" else [])
    print(f"wrote {', '.join(map(str, written))} ({fmt}; {note})")
    evo = f"evo_ape {EVO_FORMAT[fmt]} {out / (ref + SUFFIX[fmt])} {out / (est + SUFFIX[fmt])}"
    print(f"compare: {evo}" + (" -a (evo aligns; kitti pairs poses by line)" if fmt == "kitti" else
                               " (add -a or -s for evo's own alignment)"))  # fmt: skip
    return 0
