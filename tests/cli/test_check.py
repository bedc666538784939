"""`hydroilqr check`: what it reports about a task file before any solve."""

from __future__ import annotations

from hydroilqr import Task, cli
from tests.conftest import assert_one_line, edit, write_case


def test_check_warns_that_a_rigid_geometrys_modulus_is_unused():
    from hydroilqr.problem.check import check_task

    task = Task.load(
        "cartpole-wall",
        ["geometry.tip.compliance=rigid", "geometry.tip.resolution_hint=0.01"],
        smoke=True,
    )
    out = check_task(task)
    assert any("hydroelastic_modulus is not used" in w for w in out["warnings"])


def test_check_validates_the_smoke_section(tmp_path, capsys):
    path = write_case(tmp_path, edit(smoke={"solver.max_iterations": -1}))
    rc = cli.main(["check", str(path)])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "solver.max_iterations")


def test_check_names_a_deep_initial_overlap_even_when_the_rollout_survives(capsys):
    deep = "initial_state.ball_position=[0.4, 0, 0.06]"  # 4 cm into the floor
    rc = cli.main(["check", "kinova-forward", "--set", deep])
    out = capsys.readouterr().out
    assert rc == 0 and "ball_collision (ball) and ground (world) overlap by 40 mm" in out
    assert cli.main(["check", "kinova-forward"]) == 0  # resting 1.6 mm deep: no warning
    assert "overlap by" not in capsys.readouterr().out


def test_check_lists_the_ensemble_members_and_rolls_the_guess_on_each(tmp_path, capsys):
    from tests.conftest import write_task

    member = {"plant.gravity": [0, 0, -8]}
    task = write_task(tmp_path, num_steps=5, ensemble=[member], ensemble_weight=0.5)
    assert cli.main(["check", str(task)]) == 0
    out = capsys.readouterr().out
    assert "ensemble[0] (weight 0.5, guess rollout ok): plant.gravity=[0, 0, -8]" in out
    assert "check passed" in out
