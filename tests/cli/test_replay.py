"""Issue 54, item 4: the replay camera aims at the scene by default, and `hydroilqr replay`
rewrites a run's replay.html without a re-solve."""

from __future__ import annotations

import numpy as np
import pytest

from hydroilqr import Task, cli
from tests.conftest import assert_one_line, edit, write_case


def test_the_default_camera_frames_the_bodies_and_a_task_camera_wins():
    from hydroilqr.model.scene import view_box
    from hydroilqr.output.replay import camera_for, camera_note
    from tests.integration.test_model_names import NUDGE

    task = Task.from_dict(NUDGE)  # bodies 3 m below the origin: the old default missed them
    low, high = view_box(task, task.x0)
    assert low[2] < -3.0 and high[2] > -0.1  # the acrobot's links and the cube, not the ground
    pos, target = camera_for(task)
    np.testing.assert_allclose(target, (low + high) / 2)
    assert np.linalg.norm(pos - target) >= 1.8 * np.linalg.norm(high - low) - 1e-9
    assert "metric_params.camera" in camera_note(task)
    cam = {"position": [1.0, -2.0, 1.0], "target": [0.0, 0.0, 0.5]}
    set_cam = task.with_overrides({"metric_params.camera": cam})
    pos, target = camera_for(set_cam)
    assert pos.tolist() == cam["position"] and target.tolist() == cam["target"]
    assert camera_note(set_cam) == ""


def test_replay_rewrites_a_runs_replay_without_solving(tmp_path, capsys):
    path = write_case(tmp_path, edit())
    run = tmp_path / "run"
    assert cli.main(["solve", "--task-file", str(path), "--no-replay", "--out", str(run)]) == 0
    assert not (run / "replay.html").exists()
    capsys.readouterr()
    assert cli.main(["replay", str(run), "--camera", "0,-3,1:0,0,0.5"]) == 0
    assert f"wrote {run / 'replay.html'}" in capsys.readouterr().out
    assert (run / "replay.html").stat().st_size > 10_000


@pytest.mark.parametrize(
    ("extra", "needle"),
    [(["--camera", "1,2:3"], "--camera"), (["--out", "x.txt"], "--out")],
)
def test_replay_refuses_bad_arguments_in_one_line(tmp_path, capsys, extra, needle):
    rc = cli.main(["replay", str(tmp_path), *extra])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, needle)


def test_replay_of_a_directory_without_a_run_is_one_line(tmp_path, capsys):
    rc = cli.main(["replay", str(tmp_path)])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "summary.json")
