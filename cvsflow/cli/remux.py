"""``cvsflow remux``: a raw H.264 / HEVC stream (no timestamps) given frame times in an MP4."""

from __future__ import annotations

from cvsflow.exceptions import InputError


def cmd_remux(args) -> int:
    """``cvsflow remux``: copy a raw stream into an MP4 with the camera's frame times.

    Parameters
    ----------
    args : argparse.Namespace
        ``src`` (the raw stream), ``out`` (the MP4 to write, new), and one of
        ``timestamps`` (a timecode format v2 file) or ``fps`` (frames/s).

    Returns
    -------
    int
        Exit code, 0 (errors are raised as :class:`CvsflowError` and reported by ``main``).

    Raises
    ------
    InputError
        See :func:`cvsflow.io.raw_video.remux_with_times` and
        :func:`cvsflow.io.raw_video.read_timecodes_v2`.
    """
    from cvsflow.io.raw_video import read_timecodes_v2, remux_with_times

    if (args.fps is None) == (args.timestamps is None):
        raise InputError(f"{args.src}: give one of --timestamps and --fps")
    t_s = read_timecodes_v2(args.timestamps) if args.timestamps else None
    done = remux_with_times(args.src, args.out, fps=args.fps, timestamps_s=t_s)
    print(f"wrote {args.out}: {done['n_frames']} frames over {done['duration_s']:.3f} s, "
          f"median period {1000 * done['period_s']:.3f} ms (from {done['source']})")
    if done["source"] == "fps":
        print("note: times from a nominal frame rate: dropped frames and a variable rate "
              "cannot show; the camera's own timestamps (--save-pts) are better")
    return 0
