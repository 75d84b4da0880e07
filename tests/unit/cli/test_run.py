"""`cvsflow run`: the command line it gives snakemake, and the config errors it names first."""

import sys

import pytest

from cvsflow import cli
from cvsflow.cli import run as cli_run
from cvsflow.workflow.config import PROFILES, SNAKEFILE

SESSION = "sessions:\n  lab1:\n    calib_dir: calib\n    board: {squares_x: 6, squares_y: 5, square_m: 0.09}\n"


@pytest.fixture
def calls(monkeypatch):
    """The commands `cvsflow run` would execute (nothing runs)."""
    made = []
    monkeypatch.setattr(cli_run.subprocess, "call", lambda cmd: made.append(cmd) or 0)
    return made


def test_config_runs_the_package_workflow_on_it_alone(tmp_path, monkeypatch, calls):
    """A config as first argument: the package's Snakefile, the config by absolute path (no
    demo config), the package's workstation profile, then snakemake's own arguments."""
    (tmp_path / "conf").mkdir()
    (tmp_path / "conf" / "s.yaml").write_text(SESSION)
    monkeypatch.chdir(tmp_path)
    assert cli.main(["run", "conf/s.yaml", "--cores", "3", "-n"]) == 0
    assert calls[-1] == [sys.executable, "-m", "snakemake", "-s", str(SNAKEFILE), "--configfile",
                         str(tmp_path / "conf" / "s.yaml"), "--workflow-profile",
                         str(PROFILES / "default"), "--cores", "3", "-n"]
    assert (PROFILES / "default" / "config.yaml").is_file() and (PROFILES / "slurm").is_dir()


def test_a_named_profile_replaces_the_workstation_one(tmp_path, monkeypatch, calls):
    """`--workflow-profile slurm` (snakemake finds it beside the package's Snakefile) or a
    `--profile` of the user's own: the workstation profile is not added under it."""
    (tmp_path / "s.yaml").write_text(SESSION)
    monkeypatch.chdir(tmp_path)
    assert cli.main(["run", "s.yaml", "--workflow-profile", "slurm"]) == 0
    assert "--workflow-profile" in calls[-1] and str(PROFILES / "default") not in calls[-1]
    assert cli.main(["run", "s.yaml", "--profile=mine"]) == 0
    assert str(PROFILES / "default") not in calls[-1]


def test_without_config_the_folders_snakefile_runs(tmp_path, monkeypatch, calls):
    """No config: the current folder's Snakefile (the repository's demo), its own
    profiles/default left to snakemake, else the package's profile."""
    (tmp_path / "Snakefile").write_text("")
    monkeypatch.chdir(tmp_path)
    assert cli.main(["run", "-n", "--cores", "2"]) == 0
    assert calls[-1] == [sys.executable, "-m", "snakemake", "--workflow-profile",
                         str(PROFILES / "default"), "-n", "--cores", "2"]
    (tmp_path / "profiles" / "default").mkdir(parents=True)
    assert cli.main(["run", "--configfile", "x.yaml"]) == 0
    assert calls[-1] == [sys.executable, "-m", "snakemake", "--configfile", "x.yaml"]


@pytest.mark.parametrize(
    ("argv", "text", "expected"),
    [
        (["run", "missing.yaml"], None, "missing.yaml: config file not found"),
        (["run", "s.yaml"], "flights: {}\n", "s.yaml): no sessions key; expected a sessions:"),
        (["run", "s.yaml"], "sessions: {}\n", "s.yaml): sessions: {}; expected"),
        (["run", "s.yaml"], "sessions: [a\n", "s.yaml: not valid YAML at line 2, column 1"),
        (["run", "--configfile", "s.yaml"], SESSION, "the config goes first: `cvsflow run my.yaml`"),
        (["run"], None, "no config file given and no Snakefile here"),
    ],
    ids=["missing", "no-sessions", "empty-sessions", "not-yaml", "configfile-option", "nothing"],
)
def test_bad_config_is_one_named_line_and_nothing_runs(tmp_path, monkeypatch, capsys, calls, argv,
                                                       text, expected):
    """Each refused config: exit 1, one line on stderr naming the file and what is expected,
    snakemake never started."""
    if text is not None:
        (tmp_path / "s.yaml").write_text(text)
    monkeypatch.chdir(tmp_path)
    assert cli.main(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith("cvsflow: error: ") and expected in err and err.count("\n") == 1
    assert calls == []


def test_yte_template_is_left_to_snakemake(tmp_path, monkeypatch, calls):
    """A YTE template (it may run code) is not read before snakemake reads it."""
    (tmp_path / "s.yaml").write_text("__use_yte__: true\n?if True:\n  sessions: {}\n")
    monkeypatch.chdir(tmp_path)
    assert cli.main(["run", "s.yaml"]) == 0
    assert calls[-1][6] == str(tmp_path / "s.yaml")
