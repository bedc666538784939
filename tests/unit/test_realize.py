"""A position guess realized with virtual forces (``initial_guess.realize``, solver/realize.py):
the virtual actuators' partials match finite differences of the plant's step, the final plan
is the task's own plant's (no virtual force), ``check`` shows where the guess asked the base
to go and where it went, and bad settings are one-line refusals."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hydroilqr import Task, cli
from hydroilqr.model.derivatives import linearize
from hydroilqr.problem.errors import ConfigError
from hydroilqr.solver.api import solve
from hydroilqr.solver.realize import assert_physical

# The pitching hopper of hopper-hop, asked the peer's way to slide its base forward: the guess
# names the base's x (unactuated) with its joints; smoke-sized, two stages of two iterations.
TARGET = "{base_x: 0.3, hip: -0.6, knee: 1.2, ankle: -0.6}"
GUESS = f"initial_guess={{target: {TARGET}, realize: {{weights: [1.0e-3, 10], iterations: 2}}}}"
SMALL = ["search=null", "num_steps=8", "solver.max_iterations=2", GUESS]


def realized_task(extra=()) -> Task:
    return Task.load("hopper-hop", SMALL + list(extra))


def test_the_virtual_forces_partials_match_finite_differences():
    task = realized_task()
    physical = task.dynamics
    virtual = task.virtual_task(1.0).dynamics
    assert virtual.nu == physical.nu + 1  # one virtual actuator, on base_x's joint
    assert virtual.layout.actuators[-1] == "virtual_base_x"
    assert np.isinf(virtual.effort_limits[-1])
    x = task.x0
    u = np.concatenate([physical.gravity_compensation(x), [5.0]])
    for fd_forces in (False, True):  # the task's own setting is fd_forces: true
        _, B = linearize(virtual, x, u, "central", eps=1e-6, fd_forces=fd_forces)
        h = 1e-3  # independent central differences of the step on the virtual force
        du = np.zeros(virtual.nu)
        du[-1] = h
        fd = (virtual.step(x, u + du) - virtual.step(x, u - du)) / (2 * h)
        assert np.allclose(B[:, -1], fd, rtol=1e-3, atol=1e-6)
        assert np.abs(fd).max() > 1e-4  # it does push the base
    # the virtual plant with no virtual force is the task's plant, bit for bit
    assert np.array_equal(virtual.step(x, np.append(u[:-1], 0.0)), physical.step(x, u[:-1]))


def test_the_guess_itself_is_unchanged_by_realize():
    """``initial_guess`` stays the tracking rollout on the task's own plant; the realization
    starts from its tracking with the virtual forces (which follows the base's path)."""
    task = realized_task()
    plain = Task.load("hopper-hop", SMALL[:-1] + [f"initial_guess={{target: {TARGET}}}"])
    assert plain.config.initial_guess.realize is None
    N = task.steps
    assert np.array_equal(task.initial_guess(N), plain.initial_guess(N))
    bx = task.dynamics.layout.block("base_x").coords[0]
    V = task.virtual_task()
    X = V.dynamics.rollout(task.x0, V.initial_guess(N))
    X_plain = task.dynamics.rollout(task.x0, task.initial_guess(N))
    assert abs(X[-1, bx] - 0.3) < abs(X_plain[-1, bx] - 0.3)  # the target: at the end


def test_the_final_plan_has_no_virtual_force():
    task = realized_task()
    sol = solve(task)
    assert sol.U.shape == (task.steps, task.dynamics.nu)
    stages = sol.extra["realize"]["stages"]
    assert [s["weight"] for s in stages] == [1.0e-3, 10.0]
    assert all(s["iterations"] <= 2 for s in stages)
    # the plan is the task's own plant's: its controls replay to its states there
    assert np.allclose(task.dynamics.rollout(task.x0, sol.U), sol.X, atol=1e-8)
    assert_physical(task, sol)
    with pytest.raises(AssertionError, match="virtual"):
        assert_physical(task, SimpleNamespace(U=np.zeros((task.steps, task.dynamics.nu + 1))))


@pytest.mark.parametrize(
    "realize, words",
    [
        ("{weights: []}", "at least one"),
        ("{weights: [0.1, -1]}", "weights[1]: expected a finite number > 0"),
        ("{weights: [10, 0.1]}", "must not decrease"),
        ("{iterations: 0}", "iterations: must be >= 1"),
    ],
)
def test_bad_settings_are_refused_when_loaded(realize, words):
    guess = f"initial_guess={{target: {{base_x: 0.3}}, realize: {realize}}}"
    with pytest.raises(ConfigError, match=r"initial_guess\.realize") as e:
        Task.load("hopper-hop", ["search=null", guess])
    assert words in str(e.value)
    assert "\n" not in str(e.value)


def test_realize_is_refused_with_a_search_and_without_an_unactuated_coordinate():
    guess = "initial_guess={target: {base_x: 0.3}, realize: {}}"
    with pytest.raises(ConfigError, match="not with search"):
        Task.load("hopper-hop", [guess])  # hopper-hop has a search: section
    task = Task.load("hopper-hop", ["search=null", "initial_guess={target: {hip: 0}, realize: {}}"])
    with pytest.raises(ConfigError, match="moves no unactuated coordinate"):
        task.validate()
    held = "initial_guess={target: {base_z: 1.039, hip: 0}, realize: {}}"  # base_z's start
    task = Task.load("hopper-hop", ["search=null", held])
    with pytest.raises(ConfigError, match="moves no unactuated coordinate"):
        task.validate()


def test_check_shows_where_the_guess_asked_the_base_to_go_and_where_it_went(capsys):
    args = ["check", "hopper-hop"] + [a for s in SMALL for a in ("--set", s)]
    assert cli.main(args) == 0
    out = capsys.readouterr().out
    assert "unactuated, asked -> reached by the tracking rollout at the end: base_x 0.3 -> " in out
    assert "realized (initial_guess.realize), at the end: base_x " in out
    assert "largest virtual force per stage: weight 0.001: " in out


def test_the_example_realizes_the_base_coordinate_its_guess_moves():
    """examples/hopper-pitch-guess.yaml: the peer's guess (the whole configuration towards a
    target 0.7 m ahead) names the base's three coordinates but moves only its x (its height
    and pitch stay at their start values): x alone gets a virtual actuator."""
    from pathlib import Path

    path = Path(__file__).parents[2] / "examples" / "hopper-pitch-guess.yaml"
    task = Task.load(str(path), smoke=True)
    task.validate()
    virtual = task.virtual_task().dynamics
    assert virtual.layout.actuators[task.dynamics.nu :] == ["virtual_base_x"]


def test_solve_says_how_the_realization_ended(tmp_path, capsys):
    args = ["solve", "hopper-hop", "--out", str(tmp_path / "run"), "--no-replay"]
    assert cli.main(args + [a for s in SMALL for a in ("--set", s)]) in (0, 4)
    out = capsys.readouterr().out
    assert "initial_guess.realize: 2 stage(s) first" in out
    assert "realize: largest virtual force per stage (weight: N or N·m) 0.001: " in out
