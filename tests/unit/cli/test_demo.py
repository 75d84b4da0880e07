"""`cvsflow demo DIR`: the demo's config written into DIR (never over another), then run there."""

import sys
from pathlib import Path

import pytest
import yaml

from cvsflow import cli
from cvsflow.cli import demo as cli_demo
from cvsflow.exceptions import InputError
from cvsflow.workflow.config import DEMO_CONFIG, PROFILES, SNAKEFILE

REPO = Path(__file__).resolve().parents[3]


def test_the_repositorys_config_is_the_packages_demo():
    """One copy: config/config.yaml (the repository Snakefile's) is the package's demo config."""
    assert (REPO / "config" / "config.yaml").resolve() == DEMO_CONFIG
    assert (REPO / "profiles").resolve() == PROFILES


def test_duration_changes_only_the_demo_sessions_video_length():
    """--duration-s edits sessions.demo.synth.duration_s and nothing else; comments are kept."""
    base = yaml.safe_load(cli_demo.demo_config_text())
    text = cli_demo.demo_config_text(12.5)
    changed = yaml.safe_load(text)
    assert changed["sessions"]["demo"]["synth"]["duration_s"] == 12.5
    changed["sessions"]["demo"]["synth"]["duration_s"] = base["sessions"]["demo"]["synth"]["duration_s"]
    assert changed == base
    assert text.count("\n#") == cli_demo.demo_config_text().count("\n#")
    assert changed["flights"]["flight_demo"]["synth"]["duration_s"] == 60.0


def test_session_file_is_written_once_and_never_overwritten(tmp_path):
    """A new folder gets session.yaml; the same text reuses it; another text is refused and the
    file stays as it was."""
    out = tmp_path / "a" / "demo"
    session = cli_demo.write_demo_config(out, "sessions: {x: {}}\n")
    assert session == out / "session.yaml" and session.read_text() == "sessions: {x: {}}\n"
    assert cli_demo.write_demo_config(out, "sessions: {x: {}}\n") == session
    with pytest.raises(InputError, match="exists and differs from this demo's config"):
        cli_demo.write_demo_config(out, "sessions: {y: {}}\n")
    assert session.read_text() == "sessions: {x: {}}\n"
    (tmp_path / "file").write_text("")
    with pytest.raises(InputError, match="not a folder"):
        cli_demo.write_demo_config(tmp_path / "file", "x")


def test_demo_runs_its_config_in_its_folder(tmp_path, monkeypatch, capsys):
    """The workflow runs on DIR/session.yaml with DIR as its working directory (results there),
    the package's Snakefile and profile; where the results are is printed."""
    calls = []
    monkeypatch.setattr(cli_demo.subprocess, "call", lambda cmd: calls.append(cmd) or 0)
    monkeypatch.chdir(tmp_path)
    assert cli.main(["demo", "d", "--duration-s", "10", "--cores", "1"]) == 0
    session = tmp_path / "d" / "session.yaml"
    assert calls == [[sys.executable, "-m", "snakemake", "-s", str(SNAKEFILE), "--configfile", str(session),
                      "--workflow-profile", str(PROFILES / "default"), "--directory", "d", "--cores", "1"]]
    assert yaml.safe_load(session.read_text())["sessions"]["demo"]["synth"]["duration_s"] == 10.0
    assert "results in d/results" in capsys.readouterr().out


@pytest.mark.parametrize("value", ["5", "x"])
def test_too_short_a_demo_is_a_usage_error(value, capsys):
    """Under 10 s the held-out scoring cannot make its folds: refused before anything is written."""
    with pytest.raises(SystemExit) as exc:
        cli.main(["demo", "d", "--duration-s", value])
    assert exc.value.code == 2 and "--duration-s" in capsys.readouterr().err
