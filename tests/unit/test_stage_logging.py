"""A stage's log: its failure reason in one line, and on success its wall and CPU time."""

import os
import re
import subprocess
import sys
import time

import pytest

from cvsflow.exceptions import InputError
from cvsflow.io.logs import cpu_section, stage_logging


def test_a_stage_logs_its_process_cpu_time(tmp_path):
    """The ``done`` line states the process's CPU (bench/job_times.py reads it in place of
    Snakemake's sampled value): at least the CPU the stage's body burned."""
    log_path = tmp_path / "logs" / "s.log"
    with stage_logging(log_path, "s"):
        c0 = time.process_time()
        while time.process_time() - c0 < 0.3:
            pass
        burned = time.process_time()
    done = re.findall(r"stage s done in ([0-9.]+) s \(process CPU ([0-9.]+) s\)", log_path.read_text())
    assert len(done) == 1
    wall_s, cpu_s = map(float, done[0])
    assert wall_s >= 0.29 and cpu_s >= burned - 0.03  # os.times counts in clock ticks



def test_a_stage_logs_its_start_up_and_a_section_cpu(tmp_path):
    """The ``started`` line states the process's CPU so far (start-up: interpreter and imports)
    and a ``cpu_section`` block its own CPU, both read by bench/job_times.py."""
    log_path = tmp_path / "s.log"
    with stage_logging(log_path, "s") as log, cpu_section(log, "figures"):
        c0 = time.process_time()
        while time.process_time() - c0 < 0.2:
            pass
    text = log_path.read_text()
    startup = re.findall(r"stage s started \(start-up CPU ([0-9.]+) s\)", text)
    figures = re.findall(r"section figures: CPU ([0-9.]+) s", text)
    assert len(startup) == 1 and float(startup[0]) > 0
    assert len(figures) == 1 and float(figures[0]) >= 0.17  # os.times counts in clock ticks

def test_a_failed_stage_logs_its_reason_and_no_done_line(tmp_path):
    log_path = tmp_path / "s.log"
    with pytest.raises(InputError), stage_logging(log_path, "s"):
        raise InputError("video.mp4: frame 12 is not readable")
    text = log_path.read_text()
    assert "stage s failed (InputError): video.mp4: frame 12 is not readable" in text
    assert "done in" not in text and "Traceback" not in text


SCRIPT = """
from cvsflow.exceptions import InputError, ResultRangeError
from cvsflow.io.logs import cpu_section, stage_logging
import sys
with stage_logging(sys.argv[1], "s"):
    if sys.argv[2] == "named":
        raise ResultRangeError("result.yaml: fx_px 1.2e-10 outside 175..2800 px")
    raise KeyError("a bug")
"""


@pytest.mark.parametrize("debug", ["", "1"])
def test_a_failed_script_prints_the_named_error_and_log_not_a_traceback(tmp_path, debug):
    """A stage script ended by a named error (as Snakemake runs it: its own process) prints the
    one-line error with its class and the log's path on stderr, without the traceback, and
    exits 1; CVSFLOW_DEBUG=1 prints the traceback too. A bug (any other exception) keeps its
    traceback on the console and in the log."""
    log_path = tmp_path / "logs" / "s.log"
    env = {**os.environ, "CVSFLOW_DEBUG": debug}
    run = [sys.executable, "-c", SCRIPT, str(log_path)]
    named = subprocess.run([*run, "named"], capture_output=True, text=True, env=env, timeout=120)
    assert named.returncode == 1
    line = "stage s failed (ResultRangeError): result.yaml: fx_px 1.2e-10 outside 175..2800 px"
    assert line in named.stderr and line in log_path.read_text()
    assert ("Traceback" in named.stderr) == bool(debug)
    if not debug:
        assert f"its log: {log_path}" in named.stderr
    assert "Traceback" not in log_path.read_text()
    bug = subprocess.run([*run, "bug"], capture_output=True, text=True, env=env, timeout=120)
    assert bug.returncode == 1 and "Traceback" in bug.stderr and "KeyError: 'a bug'" in bug.stderr
    assert "Traceback" in log_path.read_text()
