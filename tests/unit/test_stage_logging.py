"""A stage's log: its failure reason in one line, and on success its wall and CPU time."""

import re
import time

import pytest

from cvsflow.exceptions import InputError
from cvsflow.io.logs import stage_logging


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


def test_a_failed_stage_logs_its_reason_and_no_done_line(tmp_path):
    log_path = tmp_path / "s.log"
    with pytest.raises(InputError), stage_logging(log_path, "s"):
        raise InputError("video.mp4: frame 12 is not readable")
    text = log_path.read_text()
    assert "stage s failed: video.mp4: frame 12 is not readable" in text and "done in" not in text
