"""Ctrl+C on the Dask commands (issue 39): `solve --starts` and `sweep` stop within seconds
with exit code 130 and keep what had finished, also when Ctrl+C comes while the cluster
starts (a held Ctrl+C, not an ignored one). Ctrl+C is SIGINT to the whole process group, as a
terminal sends it."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml

from tests.conftest import ACROBOT_TASK

HYDROILQR = Path(sys.executable).parent / "hydroilqr"


def _slow_task(tmp_path: Path) -> Path:
    """An acrobot solve of some seconds (AutoDiff over 200 steps)."""
    task = {**ACROBOT_TASK, "num_steps": 200}
    never = {"relative_cost_tolerance": 0.0, "expected_decrease_tolerance": 0.0}
    task["solver"] = {"max_iterations": 12, "derivatives": "autodiff", **never}
    path = tmp_path / "slow.yaml"
    path.write_text(yaml.safe_dump(task))
    return path


def _start(argv: list[str]) -> subprocess.Popen:
    return subprocess.Popen(
        [str(HYDROILQR), *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group, as a terminal's foreground job
    )


def _ctrl_c_after(p: subprocess.Popen, needle: str | None, limit: float = 240.0) -> str:
    """Waits for a line of stdout containing ``needle`` (None: no wait), sends Ctrl+C to the
    group and returns the output so far."""
    seen = []
    deadline = time.monotonic() + limit
    while needle is not None and time.monotonic() < deadline:
        line = p.stdout.readline()
        if not line:
            break
        seen.append(line)
        if needle in line:
            break
    os.killpg(p.pid, signal.SIGINT)
    return "".join(seen)


def _finish(p: subprocess.Popen, seconds: float = 30.0) -> tuple[int, float, str]:
    t0 = time.monotonic()
    try:
        out, err = p.communicate(timeout=seconds)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.communicate()
        raise AssertionError(f"still running {seconds} s after Ctrl+C") from None
    return p.returncode, time.monotonic() - t0, err


def test_ctrl_c_stops_a_multistart_and_keeps_the_finished_starts(tmp_path):
    out = tmp_path / "ms"
    argv = ["solve", str(_slow_task(tmp_path)), "--starts", "3", "--workers", "1"]
    p = _start([*argv, "--out", str(out), "--no-replay"])
    before = _ctrl_c_after(p, "start 0:")
    assert "start 0: status" in before
    rc, seconds, err = _finish(p)
    assert rc == 130 and seconds < 25, (rc, seconds, err)
    ms = json.loads((out / "summary.json").read_text())["multistart"]
    assert ms["interrupted"] is True and ms["requested"] == 3
    assert 1 <= ms["finished"] < 3 and len(ms["results"]) == ms["finished"]
    assert "Traceback" not in err, err


def test_ctrl_c_while_the_cluster_starts_stops_a_sweep(tmp_path):
    """A Ctrl+C during the cluster's start-up is held and acted on: no run to the end."""
    out = tmp_path / "sw"
    argv = ["sweep", str(_slow_task(tmp_path)), "--param", "cost.R", "--values", "0.01,0.02,0.03"]
    p = _start([*argv, "--workers", "1", "--out", str(out)])
    before = _ctrl_c_after(p, "3 to compute")  # (printed just before the cluster starts)
    assert "dask: local cluster" not in before
    rc, seconds, err = _finish(p)
    assert rc == 130 and seconds < 25, (rc, seconds, err)
    assert "interrupted" in err and "Traceback" not in err, err


def test_ctrl_c_stops_a_sweep_and_keeps_the_finished_points(tmp_path):
    out = tmp_path / "sw"
    argv = ["sweep", str(_slow_task(tmp_path)), "--param", "cost.R", "--values", "0.01,0.02,0.03"]
    p = _start([*argv, "--workers", "1", "--out", str(out)])
    before = _ctrl_c_after(p, "cost.R=0.01:")
    assert "cost.R=0.01:" in before
    rc, seconds, err = _finish(p)
    assert rc == 130 and seconds < 25, (rc, seconds, err)
    assert "finished points are kept" in err and "Traceback" not in err, err
    assert len(list((out / "points").iterdir())) >= 1
