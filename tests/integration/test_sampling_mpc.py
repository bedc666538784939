"""MPC with the sampling planners (``mpc.planner: sampling | hybrid``) at smoke size,
lock-step."""

import numpy as np
import pytest

from hydroilqr import Task
from hydroilqr.control.mpc import prepare, run_mpc
from hydroilqr.model import workers
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.mpc import MPCConfig

SMALL = ["search.samples=4", "search.knots=3", "search.iterations=2"]


def _settings(**kw):
    base = dict(duration=0.06, rate=50.0, horizon=0.06, sampling_workers=1, planner="sampling")
    return MPCConfig(**{**base, **kw})


@pytest.fixture(scope="module")
def cartpole():
    return Task.load("cartpole-wall", [*SMALL, "search.space=position"])


def test_the_loop_follows_the_sampled_plan(cartpole):
    """Position space: the plan is the best sample's PD+ law (its torques, states and the PD
    gains as K); lock-step on the controller's own plant, the first period of the loop is the
    plan's rollout, bit for bit (u = ū when x = x̄)."""
    loop = prepare(cartpole, _settings())
    loop.first_plan()
    plan = loop.plan
    assert plan.K.shape == (6, 1, 4) and np.count_nonzero(plan.K[0]) == 2  # kp on q, kd on v
    res = loop.run()
    n = loop.period_steps
    assert np.array_equal(res.X[: n + 1], plan.X[: n + 1])
    s = res.stats()
    assert s["planner"] == "sampling" and s["sampling"]["samples_per_update_mean"] == 4
    assert s["updates"] == 2 and res.failures == 0


def test_each_update_warm_starts_from_the_shifted_best(cartpole):
    """Every update's sample 0 is the previous best spline shifted by the time that passed:
    its first target is the one the plan in force holds then (position space)."""
    loop = prepare(cartpole, _settings(duration=0.1))
    loop.first_plan()
    ctrl = loop.ctrl
    before_cmd, t_before = ctrl.command.copy(), ctrl.t_plan
    loop.run()
    assert ctrl.t_plan > t_before and ctrl.updates >= 2
    lag = int(round((ctrl.t_plan - t_before) / cartpole.dynamics.dt))
    if ctrl.updates == 2:  # (one update after the first plan)
        assert np.array_equal(ctrl.command[0], before_cmd[lag])


def test_hybrid_keeps_ilqr_only_where_it_lowered_the_cost():
    task = Task.load("cartpole-wall", SMALL)  # torque space
    res = run_mpc(task, _settings(planner="hybrid", iterations_per_update=1))
    for u in res.sampling:
        assert u["plan_cost"] <= u["best_cost"] + 1e-9
    assert res.stats()["sampling"]["ilqr_iterations_mean"] >= 0


def test_sample_rollouts_are_the_same_on_worker_processes(cartpole):
    dyn = cartpole.dynamics
    rng = np.random.default_rng(0)
    qi = [1]
    commands = [cartpole.x0[qi] + 0.3 * rng.standard_normal((7, 1)) for _ in range(5)]
    here = workers.sample_rollouts(dyn, cartpole.x0, commands, "position", 50.0, 5.0, 1)
    workers.warm_up(dyn, 2)
    there = workers.sample_rollouts(dyn, cartpole.x0, commands, "position", 50.0, 5.0, 2)
    for a, b in zip(here, there):
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


@pytest.mark.parametrize(
    "kw, key",
    [
        ({"planner": "mppc"}, "mpc.planner"),
        ({"samples": 1}, "mpc.samples"),
        ({"sampling_iterations": 0}, "mpc.sampling_iterations"),
        ({"shrinking_horizon": True, "duration": 0.05}, "mpc.shrinking_horizon"),
        ({"candidates": ["guess"]}, "mpc.candidates"),
    ],
)
def test_sampling_settings_are_refused_before_any_work(cartpole, kw, key):
    with pytest.raises(ConfigError, match=key):
        prepare(cartpole, _settings(**kw))
