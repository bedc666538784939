"""Issue 53, 14: `check` follows each free or planar base along the guess: where it ends,
and warnings when it falls below every contact geometry, leaves the scene, or moves far
faster than the task's scale (a guess that sent a base 11 m through the ground passed)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from hydroilqr import Task, cli
from hydroilqr.studies.check import check_task

MODELS = Path(__file__).resolve().parents[2] / "src" / "hydroilqr" / "models"


def _falling_ball(tmp_path: Path, **state) -> Path:
    """A cart-pole beside a table, and a free ball that starts 2.5 m beside the table."""
    task = {
        "models": [
            {"file": str(MODELS / "cartpole_wall" / "cartpole.sdf")},
            {"file": str(MODELS / "kinova_gen3" / "ball.sdf")},
        ],
        "scene": [
            {"name": "table", "shape": "box", "size": [1.0, 1.0, 0.1], "compliance": "rigid"}
        ],
        "initial_state": {"ball.position": [3.0, 0.0, 0.5], **state},
        "num_steps": 150,
        "cost": {"Q": {"cart_slider": 1.0}},
    }
    path = tmp_path / "fall.yaml"
    path.write_text(yaml.safe_dump(task))
    return path


def test_a_base_that_falls_past_everything_is_warned_about_and_its_end_printed(tmp_path, capsys):
    assert cli.main(["check", str(_falling_ball(tmp_path))]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "ball (free base) after 150 steps of the guess: at (3.00, 0.00, -10." in out
    assert "ball falls below every contact geometry along the guess" in out
    assert "the lowest surface is at -0.05 m" in out  # (the table's underside)
    assert "ball leaves the scene along the guess" in out
    assert "far beyond the task's scale" not in out  # a fall of 1.5 s is no such speed
    assert "check passed with 2 warning(s)" in out


def test_a_base_thrown_far_faster_than_the_scene_allows_is_warned_about(tmp_path, capsys):
    path = _falling_ball(tmp_path, **{"ball.velocity": [0.0, 0.0, -60.0]})
    assert cli.main(["check", str(path)]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "ball reaches" in out and "far beyond the task's scale" in out


@pytest.mark.parametrize("name", ["hopper-forward", "cheetah-trot-1.0", "kinova-forward"])
def test_the_built_in_guesses_keep_their_bases_in_the_scene(name):
    report = check_task(Task.load(name, smoke=True))
    bases = report["bases"]
    assert bases["bodies"] and bases["warnings"] == []
    assert not any("free base" in w or "leaves the scene" in w for w in report["warnings"])
