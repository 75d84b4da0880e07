"""``cvsflow demo DIR``: the demo session rendered into a folder of its own and run there."""

from __future__ import annotations

import argparse
import logging
import re
import subprocess
from pathlib import Path

import yaml

from cvsflow.cli.run import run_command
from cvsflow.exceptions import InputError
from cvsflow.io.files import atomic_output
from cvsflow.workflow.config import DEMO_CONFIG

log = logging.getLogger(__name__)

#: The shortest demo (s): the held-out scoring's 5 folds of 2 s blocks need 10 s of video.
MIN_DURATION_S = 10.0

# The demo session's video length: the first `duration_s:` of the file (sessions.demo.synth).
_DURATION = re.compile(r"^(\s+duration_s:\s*)([0-9.]+)", re.M)


def duration_arg(text: str) -> float:
    """``--duration-s``: seconds of rendered video, at least :data:`MIN_DURATION_S`.

    Parameters
    ----------
    text : str
        The option's value.

    Returns
    -------
    float
        Seconds (argparse's usage error, exit 2, outside 10 to 3600 s or not a number).
    """
    try:
        value = float(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"--duration-s {text!r}: expected seconds, e.g. 20") from exc
    if not MIN_DURATION_S <= value <= 3600.0:
        raise argparse.ArgumentTypeError(
            f"--duration-s {text}: expected {MIN_DURATION_S:g} to 3600 s (the held-out scoring's "
            "5 folds of 2 s need 10 s)"
        )
    return value


def demo_config_text(duration_s: float | None = None) -> str:
    """The demo's config file, comments kept, with the demo session's video length changed.

    Parameters
    ----------
    duration_s : float, optional
        Seconds of rendered video of session ``demo``; None keeps the file's (20 s).

    Returns
    -------
    str
        The text of the package's demo config (``cvsflow/workflow/demo.yaml``).
    """
    text = DEMO_CONFIG.read_text(encoding="utf-8")
    if duration_s is None:
        return text
    text = _DURATION.sub(lambda m: f"{m[1]}{float(duration_s)!r}", text, count=1)
    # the edit is on text (to keep the comments): check it changed the key it means to
    got = yaml.safe_load(text)["sessions"]["demo"]["synth"]["duration_s"]
    if got != duration_s:
        raise RuntimeError(f"{DEMO_CONFIG}: the first duration_s is not sessions.demo.synth's")
    return text


def write_demo_config(out: Path, text: str) -> Path:
    """``out/session.yaml`` holding ``text``: written if absent, reused if identical.

    Parameters
    ----------
    out : Path
        The demo's folder (created if needed).
    text : str
        The config to write.

    Returns
    -------
    Path
        The session file.

    Raises
    ------
    InputError
        ``out`` is a file, or ``out/session.yaml`` exists with other content (never overwritten).
    """
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: not a folder (expected a new folder or an earlier demo's)")
    session = out / "session.yaml"
    if session.exists():
        if session.read_text(encoding="utf-8") != text:
            raise InputError(
                f"{session}: exists and differs from this demo's config (another --duration-s, "
                "or edited); expected a new folder or the same options. Run that file with "
                f"`cvsflow run {session.name}` in {out}; nothing was overwritten"
            )
        return session
    out.mkdir(parents=True, exist_ok=True)
    with atomic_output(session) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return session


def cmd_demo(args) -> int:
    """``cvsflow demo DIR``: write the demo's config as ``DIR/session.yaml`` and run it in DIR.

    Parameters
    ----------
    args : argparse.Namespace
        ``dir``, ``duration_s`` (None: the demo's 20 s), ``cores`` (None: the profile's).

    Returns
    -------
    int
        Snakemake's exit code: the workflow renders the session's inputs into ``DIR/data/``
        and writes ``DIR/results/``, ``DIR/logs/``, ``DIR/benchmarks/``.

    Raises
    ------
    InputError
        DIR is a file, or its ``session.yaml`` is another config.
    """
    out = Path(args.dir)
    session = write_demo_config(out, demo_config_text(args.duration_s))
    extra = ["--directory", str(out)]
    if args.cores:
        extra += ["--cores", str(args.cores)]
    cmd = run_command(session, extra, Path.cwd())
    log.info("running %s", " ".join(cmd))
    code = subprocess.call(cmd)
    if code == 0:
        print(f"cvsflow demo: results in {out / 'results'} (headline numbers: "
              f"{out / 'results' / 'headline.csv'})")
        print(f"  again, or after editing a key:  cd {out} && cvsflow run session.yaml")
        print(f"  the HTML report:               cd {out} && cvsflow run session.yaml --report report.html")
        print("  your own recording:            cvsflow init RECORDING_DIR --out my_session.yaml, "
              "then cvsflow run my_session.yaml")
    return code
