"""Robust (ensemble) iLQR: the stacked dynamics, partials and cost of model/ensemble.py, and
``solve`` of a task with ``ensemble:`` members (solver/robust.py). Smoke-sized acrobots."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hydroilqr import Task, solve
from hydroilqr.metrics import validate_task
from hydroilqr.model.derivatives import Linearizer
from hydroilqr.model.ensemble import EnsembleCost, EnsembleDynamics, EnsembleLinearizer
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.solver import SolverConfig
from hydroilqr.solver.loop import solve as ilqr_solve
from hydroilqr.solver.robust import ensemble_problem
from tests.conftest import ACROBOT_TASK

HEAVY = {"actuators.elbow.rotor_inertia": 0.05}  # the elbow's reflected inertia
WEAK_GRAVITY = {"plant.gravity": [0.0, 0.0, -8.0]}


@pytest.fixture(scope="module")
def task():
    return Task.from_dict({**ACROBOT_TASK, "num_steps": 10, "solver": {"max_iterations": 4}})


@pytest.fixture(scope="module")
def robust(task):
    return task.with_overrides({"ensemble": [HEAVY, WEAK_GRAVITY], "ensemble_weight": 0.5})


def _guess(N: int, nu: int) -> np.ndarray:
    return 0.5 * np.sin(np.linspace(0.0, 3.0, N))[:, None] * np.ones((1, nu))


def test_identical_members_reproduce_the_single_rollout(task):
    twin = Task(task.config).dynamics  # its own plant
    ens = EnsembleDynamics([task.dynamics, twin])
    U = _guess(10, 1)
    X = task.dynamics.rollout(task.x0, U)
    XE = ens.rollout(ens.stack(task.x0), U)
    assert XE.shape == (11, 2 * task.dynamics.nx)
    for m in range(2):
        np.testing.assert_array_equal(ens.member_states(XE, m), X)
    np.testing.assert_array_equal(ens.step(XE[3], U[3]), XE[4])
    # closed loop: feedback on the first block only equals the single model's closed loop
    rng = np.random.default_rng(1)
    K1 = 0.3 * rng.standard_normal((10, 1, task.dynamics.nx))
    kappa = 0.2 * rng.standard_normal((10, 1))
    K = np.concatenate([K1, np.zeros_like(K1)], axis=2)
    Xs, Us = task.dynamics.closed_loop_rollout(task.x0, U, X, K1, kappa, 0.5)
    XEc, UEc = ens.closed_loop_rollout(ens.stack(task.x0), U, XE, K, kappa, 0.5)
    np.testing.assert_allclose(UEc, Us, rtol=0, atol=1e-12)
    for m in range(2):
        np.testing.assert_allclose(ens.member_states(XEc, m), Xs, rtol=0, atol=1e-10)


def test_ensemble_partials_are_the_members_blocks(robust):
    problem = ensemble_problem(robust)
    dyn = problem.dynamics
    s = SolverConfig(derivatives="central", threads=1)
    U = _guess(6, dyn.nu)
    X = dyn.rollout(problem.x0, U)
    A, B = EnsembleLinearizer.from_settings(dyn, s)(X, U, rollout=True)
    n, M = dyn.n, dyn.M
    assert A.shape == (6, M * n, M * n) and B.shape == (6, M * n, dyn.nu)
    for d, b in zip(dyn.members, dyn.blocks):
        Am, Bm = Linearizer.from_settings(d, s)(X[:, b], U, rollout=True)
        np.testing.assert_array_equal(A[:, b, b], Am)
        np.testing.assert_array_equal(B[:, b], Bm)
        other = [c for c in range(M * n) if not b.start <= c < b.stop]
        assert not A[:, b][:, :, other].any()
    # against central differences of the stacked step
    k, h = 2, 1e-6
    z = np.concatenate([X[k], U[k]])
    J = np.empty((M * n, z.size))
    for i in range(z.size):
        dz = np.zeros_like(z)
        dz[i] = h
        hi = dyn.step((z + dz)[: M * n], (z + dz)[M * n :])
        lo = dyn.step((z - dz)[: M * n], (z - dz)[M * n :])
        J[:, i] = (hi - lo) / (2 * h)
    np.testing.assert_allclose(J[:, : M * n], A[k], atol=1e-6)
    np.testing.assert_allclose(J[:, M * n :], B[k], atol=1e-6)


def test_ensemble_cost_is_the_weighted_sum(robust):
    problem = ensemble_problem(robust)
    dyn, cost = problem.dynamics, problem.cost
    assert isinstance(cost, EnsembleCost)
    np.testing.assert_array_equal(cost.weights, [1.0, 0.5, 0.5])
    U = _guess(8, dyn.nu)
    X = dyn.rollout(problem.x0, U)
    parts = [(w, c, X[:, b]) for w, c, b in zip(cost.weights, cost.members, dyn.blocks)]
    assert cost.total(X, U) == pytest.approx(sum(w * c.total(Xm, U) for w, c, Xm in parts))
    np.testing.assert_allclose(
        cost.stage_costs(X, U), sum(w * c.stage_costs(Xm, U) for w, c, Xm in parts)
    )
    br = cost.breakdown(X, U)
    assert br["R"] == pytest.approx(sum(w * c.breakdown(Xm, U)["R"] for w, c, Xm in parts))
    q = cost.quadratize(X, U)
    for (w, c, Xm), b in zip(parts, dyn.blocks):
        qm = c.quadratize(Xm, U)
        np.testing.assert_allclose(q.lx[:, b], w * qm.lx)
        np.testing.assert_allclose(q.lxx[:, b, b], w * qm.lxx)
    np.testing.assert_allclose(q.lu, sum(w * c.quadratize(Xm, U).lu for w, c, Xm in parts))
    np.testing.assert_allclose(q.luu, sum(w * c.quadratize(Xm, U).luu for w, c, Xm in parts))
    assert not q.lxx[:, dyn.blocks[0], dyn.blocks[1]].any()


def test_robust_solve_decreases_the_summed_cost(robust):
    robust = robust.with_overrides({"ensemble_warm_start": False})  # from the guess itself
    validate_task(robust)
    sol = solve(robust)
    n = robust.dynamics.nx
    assert sol.X.shape == (robust.steps + 1, n) and sol.K.shape == (robust.steps, 1, n)
    assert sol.costs[-1] < sol.costs[0]
    problem = ensemble_problem(robust)
    XE = problem.dynamics.rollout(problem.x0, sol.U)
    np.testing.assert_array_equal(sol.X, XE[:, :n])  # the nominal member's trajectory
    assert sol.final_cost == pytest.approx(problem.cost.total(XE, sol.U))
    members = sol.extra["ensemble"]["members"]
    assert "weighted sum" in sol.extra["ensemble"]["costs"]
    assert [m["overrides"] for m in members] == [{}, HEAVY, WEAK_GRAVITY]
    assert sum(m["weight"] * m["final_cost"] for m in members) == pytest.approx(sol.final_cost)
    assert members[0]["final_cost"] == pytest.approx(robust.cost.total(sol.X, sol.U))
    assert all(np.isfinite(m["terminal_error"]) for m in members)


def test_warm_start_solves_the_task_alone_first(task, robust):
    warm = solve(task)  # the task alone, from its initial guess
    sol = solve(robust)  # ensemble_warm_start: true (the default)
    problem = ensemble_problem(robust)
    ensemble_cost = lambda U: problem.cost.total(problem.dynamics.rollout(problem.x0, U), U)  # noqa: E731
    info = sol.extra["ensemble"]
    assert info["warm_start"]["iterations"] == warm.iterations
    assert info["warm_start"]["final_cost"] == pytest.approx(warm.final_cost)
    # the history: the warm start's (the task's own cost), then from the warm plan on the
    # ensemble objective
    np.testing.assert_array_equal(sol.costs[: warm.iterations], warm.costs[:-1])
    assert sol.iterations > warm.iterations
    assert info["ensemble_start_cost"] == pytest.approx(ensemble_cost(warm.U))
    assert sol.costs[warm.iterations] == info["ensemble_start_cost"]
    assert sol.initial_cost == info["guess_ensemble_cost"]  # as final_cost: the ensemble's
    assert sol.final_cost == pytest.approx(ensemble_cost(sol.U))
    assert sol.final_cost <= info["ensemble_start_cost"]
    # the status is judged from the ensemble objective of the guess, not the task's own cost
    assert info["guess_ensemble_cost"] == pytest.approx(ensemble_cost(robust.initial_guess(10)))
    assert sol.final_cost < info["guess_ensemble_cost"]
    assert sol.status in ("converged", "stalled", "max_iterations")
    # its explanation names the objective it was judged on, from the guess's value
    from hydroilqr.solver.explain import explain

    assert f"ensemble objective {info['guess_ensemble_cost']:.6g} -> " in explain(sol, robust)


def test_without_ensemble_the_solve_is_unchanged(task):
    U0 = task.initial_guess(task.steps)
    ref = ilqr_solve(task.problem(), U0, task.config.solver)  # the plain code path
    for t in (task, task.with_overrides({"ensemble": []})):
        sol = solve(t)
        np.testing.assert_array_equal(sol.X, ref.X)
        np.testing.assert_array_equal(sol.K, ref.K)
        np.testing.assert_array_equal(sol.costs, ref.costs)
        assert "ensemble" not in sol.extra


def test_member_that_changes_the_time_step_is_refused(task):
    with pytest.raises(ConfigError, match=r"ensemble\[0\]: plant.time_step cannot change"):
        task.with_overrides({"ensemble": [{"plant.time_step": 0.01}]})
    nested = task.with_overrides({"ensemble": [{"plant": {"time_step": 0.01}}]})
    with pytest.raises(ConfigError, match=r"ensemble\[0\]: the time grid") as e:
        validate_task(nested)
    assert "\n" not in str(e.value)
    from hydroilqr.control.mpc import check_settings
    from hydroilqr.problem.mpc import MPCConfig

    # mpc: the nominal model
    check_settings(MPCConfig(), task.with_overrides({"ensemble": [HEAVY]}))


def test_a_member_whose_coordinates_mean_other_joints_is_refused(tmp_path):
    """Members share the nominal's x0 and controls: a model whose joints are named otherwise
    (here the elbow renamed knee) is refused in one line, not fed the wrong coordinates."""
    from pydrake.common import FindResourceOrThrow

    from tests.conftest import write_task

    urdf = Path(FindResourceOrThrow("drake/examples/acrobot/Acrobot.urdf")).read_text()
    knee = tmp_path / "knee.urdf"
    knee.write_text(urdf.replace('name="elbow"', 'name="knee"'))
    base = {**ACROBOT_TASK, "blocks": {"angles": ["shoulder"]}}
    member = {"models.0.file": str(knee)}
    task = Task.load(str(write_task(tmp_path, base, num_steps=5, ensemble=[member])))
    with pytest.raises(ConfigError, match=r"ensemble\[0\]: orders or names the state"):
        validate_task(task)


def test_stopped_in_the_warm_start_says_the_plan_is_not_robust(robust):
    from hydroilqr.solver.explain import explain

    sol = solve(robust, callbacks=lambda info: True)  # stops after the first iteration
    assert sol.reason == "callback" and sol.extra["ensemble"]["stopped_in"] == "warm_start"
    assert sol.X.shape == (robust.steps + 1, robust.dynamics.nx)  # the task's own plan
    assert "warm start: the plan is the task's own, not robust" in explain(sol, robust)
