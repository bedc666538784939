"""Settings are checked once, where the library takes them in (issue 50, item 3): building a
task checks each of its sections once; below that, typed settings are trusted (the iLQR loop,
a closed loop's updates and stages do not check them again)."""

from __future__ import annotations

import sys
from collections import Counter

import pytest

from hydroilqr import Task
from hydroilqr.control import mpc as mpc_control
from hydroilqr.problem import (
    cost,
    goal,
    guess,
    load,
    mpc,
    plant,
    receding,
    search,
    solver,
    task,
    terms,
    variants,
)
from hydroilqr.solver.api import solve

#: Every check of a task's settings: the whole task's, each section's, and a solve's own.
VALIDATORS = [
    load.validate,
    variants.validate_variants,
    plant.validate_plant,
    task.validate_task,
    solver.validate_solver,
    mpc.validate_mpc,
    goal.validate_goal,
    cost.validate_cost,
    terms.validate_term,
    receding.validate_receding_horizon,
    search.validate_search,
    guess.validate_position_guess,
    task.validate_for_solve,
]


@pytest.fixture
def calls(monkeypatch) -> Counter:
    """Calls of each validator by name: every reference to it in a loaded hydroilqr module
    (the ``from x import f`` copies too) replaced by a counting wrapper."""
    counts: Counter = Counter()
    for fn in VALIDATORS:

        def counting(*args, _fn=fn, **kwargs):
            counts[_fn.__name__] += 1
            return _fn(*args, **kwargs)

        for mod in list(sys.modules.values()):
            if getattr(mod, "__name__", "").startswith("hydroilqr"):
                for name, value in list(vars(mod).items()):
                    if value is fn:
                        monkeypatch.setattr(mod, name, counting)
    return counts


def test_a_solve_checks_each_setting_once(calls):
    """Loading the task checks each section once; solving it adds the one check a solve
    needs (a cost to optimize) and checks no section again, however many iterations."""
    t = Task.load("hopper-forward", overrides={"num_steps": 4, "solver.max_iterations": 2})
    after_load = dict(calls)
    assert after_load == {
        "validate": 1,
        "validate_variants": 1,
        "validate_plant": 1,
        "validate_task": 1,
        "validate_solver": 1,
        "validate_mpc": 1,
        "validate_goal": 2,  # the task's goal and the closed loop's (mpc.goal)
        "validate_cost": 1,
        "validate_term": len(t.config.cost.terms),  # each of its terms once
        "validate_receding_horizon": 1,
        "validate_search": 1,
        "validate_position_guess": 1,
    }
    solve(t)
    assert dict(calls) == {**after_load, "validate_for_solve": 1}


def test_a_closed_loop_checks_its_settings_once_not_per_update(calls):
    """prepare checks the loop's settings (the task's own mpc: section was checked with the
    task); its updates check nothing again."""
    t = Task.load("cartpole-wall", overrides={"mpc.duration": 0.05, "mpc.realtime": False})
    loaded = dict(calls)
    loop = mpc_control.prepare(t)
    assert dict(calls) == {**loaded, "validate_for_solve": 1}
    result = loop.run()
    assert len(result.update_times) >= 3  # (after the first plan)
    assert dict(calls) == {**loaded, "validate_for_solve": 1}


def test_settings_changed_in_python_are_checked_by_prepare_the_sections_values_are_not(calls):
    """As the mpc command does: the task's section with the loop's duration changed is not
    checked again; a changed planner setting is checked once, by prepare."""
    t = Task.load("cartpole-wall", overrides={"mpc.realtime": False})
    loaded = dict(calls)
    mpc_control.prepare(t, mpc_control.mpc_config(t, duration=0.05))
    assert dict(calls) == {**loaded, "validate_for_solve": 1}
    mpc_control.prepare(t, mpc_control.mpc_config(t, duration=0.05, line_search_steps=2))
    assert dict(calls) == {
        **loaded,
        "validate_for_solve": 2,
        "validate_mpc": loaded["validate_mpc"] + 1,
        "validate_goal": loaded["validate_goal"] + 1,
    }
