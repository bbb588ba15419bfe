"""Ctrl-C during a real ingest says what finished and how to resume."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
from ingest_media import make_video


@pytest.mark.slow
@pytest.mark.timeout(400)
def test_sigint_during_ingest_reports_and_resumes(tmp_path):
    video = make_video(tmp_path / "walk.mp4", n=60, fps=10)
    work = tmp_path / "work"
    cmd = [sys.executable, "-m", "vid2sim.cli", "ingest", str(video), "--registry", str(tmp_path / "reg"),
           "--workdir", str(work), "--num-cpus", "1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "RAY_ENABLE_UV_RUN_RUNTIME_ENV": "0"})
    deadline = time.time() + 240
    while not (work.is_dir() and any(work.iterdir())) and time.time() < deadline and proc.poll() is None:
        time.sleep(0.5)  # wait until a clip's first stage has started writing
    assert proc.poll() is None, proc.communicate()
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, (proc.returncode, err[-2000:])
    assert "interrupted:" in err and "0 clip(s) committed" in err and "resume:" in err and str(work) in err
    assert "Traceback" not in err
