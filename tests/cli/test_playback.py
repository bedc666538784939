"""`hydroilqr playback` beside `hydroilqr solve` on the same run directory."""

from __future__ import annotations

import pytest


def test_a_plan_being_played_is_not_replaced_and_playback_dirs_hold_no_runs(tmp_path):
    import json

    from hydroilqr.output import report
    from hydroilqr.problem.config import ConfigError

    run = tmp_path / "run"
    run.mkdir()
    (run / "summary.json").write_text(json.dumps({"task": "t"}))
    with pytest.raises(ConfigError, match="playback directory"):
        report.output_dir(run / "playback-pd", "t")
    assert report.output_dir(run / "playback-pd", "t", playback=True).is_dir()
    # another process reads (plays) the run: a solve into it is refused meanwhile
    import subprocess
    import sys

    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys, time; from pathlib import Path; from hydroilqr.output import report; "
         f"report.read_lock(Path({str(run)!r})); print('held', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(ConfigError, match="in use by another hydroilqr run"):
            report._lock(run)
    finally:
        holder.kill()
        holder.wait()
