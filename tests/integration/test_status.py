"""Honest status (issue 26): what a solve's result is worth, and why."""

import json

import pytest

from hydroilqr import ConfigError, Solution, Task, explain, solve
from hydroilqr.solver import stopping

FAR = ["initial_state.ball_position=[2.0, 0.0, 0.0984]"]  # out of the arm's reach


@pytest.mark.parametrize(
    "data",
    [
        {"extends": "kinova-forward.yaml", "cost": None},
        {"extends": "cartpole-wall.yaml", "cost": {"Q": None, "Qf": None, "R": 0.0}},
    ],
)
def test_a_task_whose_cost_has_no_terms_is_refused(data):
    from hydroilqr.problem.files import task_file

    task = Task.from_dict(data, base_dir=task_file("kinova-forward").parent)  # a plant: fine
    with pytest.raises(ConfigError, match=r"^cost: no terms") as e:
        solve(task)
    assert "\n" not in str(e.value)


def test_a_start_without_contact_with_the_object_is_no_progress(tmp_path):
    task = Task.load("kinova-forward", overrides=FAR, smoke=True)
    sol = solve(task)
    assert sol.status == "no_progress" and not sol.converged
    assert "contact" in explain(sol, task)
    sol.save(tmp_path)
    back = Solution.load(tmp_path)
    assert back.status == "no_progress" and back.stats()["status"] == "no_progress"
    assert json.loads(json.dumps(back.stats()))["converged"] is False


def test_a_normal_smoke_solve_converges():
    task = Task.load("kinova-up", smoke=True)
    sol = solve(task)
    assert sol.status in ("converged", "stalled") and sol.converged
    assert stopping.improved([sol.initial_cost, sol.final_cost])
    assert explain(sol, task).startswith(("converged", "stalled"))


def test_status_definitions():
    assert stopping.status("expected_decrease", [10.0, 9.0]) == "converged"
    assert stopping.status("relative_cost_change", [10.0, 9.9999]) == "no_progress"
    assert stopping.status("stalled", [10.0, 5.0]) == "stalled"
    assert stopping.status("line_search_failed", [10.0, 10.0]) == "no_progress"
    assert stopping.status("regularization_max", [10.0, 5.0]) == "failed"
    assert stopping.status("interrupted", [10.0]) == "interrupted"
    assert stopping.status("max_iterations", [10.0, 5.0]) == "max_iterations"
    assert stopping.worst(["converged", "no_progress", "stalled"]) == "no_progress"
    assert set(stopping._ORDER) == set(stopping.STATUSES)
