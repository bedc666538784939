"""solver.convergence_window: the relative-cost-change test over the last N iterations."""

import dataclasses

import pytest

from hydroilqr import ConfigError, Task
from hydroilqr.problem.solver import SolverConfig, validate_solver
from hydroilqr.solver import stopping

TOL = 1e-3
# large decreases, then one nearly flat full step (0.09 %: below TOL alone)
COSTS = [43.04, 42.91, 40.08, 34.95, 33.19, 32.143, 32.114]


def settings(window: int) -> SolverConfig:
    return SolverConfig(relative_cost_tolerance=TOL, convergence_window=window)


def rel(costs):
    return (costs[-2] - costs[-1]) / abs(costs[-2])


def test_one_flat_full_step_ends_the_solve_only_with_the_default_window():
    assert stopping.small_full_step(rel(COSTS), 1.0, settings(1), COSTS)
    assert not stopping.small_full_step(rel(COSTS), 1.0, settings(5), COSTS)


def test_a_window_of_flat_iterations_ends_it_with_a_full_step():
    flat = [*COSTS, 32.11, 32.10, 32.09, 32.08]  # the last 5: 0.1 % together (< 5 x TOL)
    assert stopping.small_full_step(rel(flat), 1.0, settings(5), flat)
    assert not stopping.small_full_step(rel(flat), 0.5, settings(5), flat)  # not a full step
    assert not stopping.small_full_step(rel(flat[:5]), 1.0, settings(5), flat[:5])  # too few


def test_the_default_is_one_step():
    assert SolverConfig().convergence_window == 1


def test_a_window_below_one_is_refused_in_one_line():
    with pytest.raises(ConfigError, match=r"^solver.convergence_window: must be >= 1, got 0$"):
        validate_solver(dataclasses.replace(SolverConfig(), convergence_window=0))
    with pytest.raises(ConfigError, match="convergence_window") as e:
        Task.load("cartpole-wall", overrides=["solver.convergence_window=0"], smoke=True)
    assert "\n" not in str(e.value)
