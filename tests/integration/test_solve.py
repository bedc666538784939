"""Solves through solver.api/solver.loop: the plant steps, cart-pole solves, stopping and gains."""

import json

import numpy as np
import pytest

from hydroilqr import Task, solve
from hydroilqr.model.state import StateLayout
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.solver import SolverConfig
from hydroilqr.solver.ilqr import backward_pass
from hydroilqr.solver.loop import solve as ilqr_solve


def test_falling_body_falls(tmp_path):
    """A discrete plant's step must really advance (drake-notes: sampled-output-port trap)."""
    from hydroilqr.problem.files import TASKS_DIR

    task = Task.from_dict(
        {
            "models": [
                {"file": str(TASKS_DIR / "../models/cartpole_wall/cartpole.sdf")},
                {"file": str(TASKS_DIR / "../models/kinova_gen3/ball.sdf")},
            ],
            "plant": {"time_step": 0.01},
            "initial_state": {"ball.position": [2.0, 0.0, 1.0], "pole_pin": 0.3},
        }
    )
    dyn = task.dynamics
    X = dyn.rollout(task.x0, np.zeros((30, dyn.nu)))
    z = X[:, dyn.layout.block("ball.position").coords[2]]
    assert z[-1] < z[0] - 0.3  # ~0.44 m after 0.3 s of free fall
    assert np.all(np.diff(z) <= 1e-12)
    assert X[-1, dyn.layout.block("pole_pin").coords[0]] < 0.3  # the pole swings down


def test_cartpole_smoke_solve_reaches_into_the_wall(tmp_path):
    from hydroilqr import metrics

    task = Task.load("cartpole-wall", smoke=True)
    sol = solve(task)
    assert np.all(np.diff(sol.costs) < 0), "cost must decrease monotonically"
    assert sol.costs[-1] < 0.05 * sol.costs[0]
    m = metrics.compute(task, sol)
    # The tip reaches into the wall. (After only 15 iterations the overlap is a fraction of a
    # millimetre, within the tip's mesh resolution, so a contact surface may not exist yet:
    # wall_contact_steps is not asserted; measured 0 with numpy 2.4.6, 1+ with 30 iterations.)
    assert m["max_overlap_m"] > 0
    # The pole is brought from 0.5 rad past upright to near upright, braced on the wall.
    assert m["final_angle_error_rad"] < 0.25
    assert set(sol.phase_seconds) == {"rollout", "derivatives", "backward_pass", "line_search"}
    assert sol.K.shape == (task.config.steps, 1, 4) and sol.X.shape == (task.config.steps + 1, 4)
    sol.save(tmp_path / "s.npz")
    from hydroilqr import Solution

    back = Solution.load(tmp_path / "s.npz")
    np.testing.assert_array_equal(back.X, sol.X)
    assert back.reason == sol.reason


def test_blown_up_step_is_a_simulation_error(cartpole):
    """A state that explodes is reported (and rejected by a line search), never returned."""
    from hydroilqr.model.plant import SimulationError

    dyn = cartpole.dynamics
    x = np.zeros(dyn.nx)
    x[-1] = 1e7  # pole spinning at 1e7 rad/s
    with pytest.raises(SimulationError, match="diverged"):
        dyn.step(x, np.zeros(dyn.nu))


def test_cost_reference_tracks_a_solved_run(tmp_path):
    from hydroilqr.problem.errors import ConfigError

    task = Task.load("cartpole-wall", ["num_steps=20", "solver.max_iterations=3"])
    sol = solve(task)
    sol.save(tmp_path / "solution.npz")
    tracked = Task.load("cartpole-wall", [f"cost.reference={tmp_path}"])
    np.testing.assert_allclose(tracked.cost.nominal(sol.t), sol.X)
    # Between samples: linear in time; after the end: the last state held.
    mid = tracked.cost.nominal(np.array([0.5 * (sol.t[3] + sol.t[4])]))[0]
    np.testing.assert_allclose(mid, 0.5 * (sol.X[3] + sol.X[4]))
    np.testing.assert_allclose(tracked.cost.nominal(np.array([9.0]))[0], sol.X[-1])
    # Only the listed blocks follow the reference; the others keep the task's nominal.
    part = Task.load(
        "cartpole-wall",
        [f"cost.reference={tmp_path}", "cost.reference_blocks=[pole_angle]"],
    )
    x = part.cost.nominal(sol.t)
    pole = part.dynamics.layout.block("pole_angle").coords[0]
    cart = part.dynamics.layout.block("cart_position").coords[0]
    np.testing.assert_allclose(x[:, pole], sol.X[:, pole])
    np.testing.assert_allclose(x[:, cart], 0.0)
    # The solve against the reference from the same start has (near) zero state error.
    assert tracked.cost.breakdown(sol.X, sol.U)["Q.pole_angle"] < 1e-20
    with pytest.raises(ConfigError, match="cost.reference"):
        _ = Task.load("cartpole-wall", [f"cost.reference={tmp_path / 'none'}"]).cost
    # A run of other models (its summary.json says which) is not a reference for this task.
    summary = {"task": "acrobot", "config": {"models": [{"file": "package://x/Acrobot.urdf"}]}}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    with pytest.raises(ConfigError, match="is a run of other models"):
        _ = Task.load("cartpole-wall", [f"cost.reference={tmp_path}"]).cost


def test_short_accepted_steps_raise_mu_and_full_steps_lower_it(monkeypatch):
    """The μ update after an accepted step, with the step lengths forced: trials longer than
    this iteration's cap fail (as a contact solve that does not converge), so iterations 1-2
    accept a short step (1/32 < short_step) and 3-4 a full one. (It used to read whichever
    steps a kinova contact solve happened to take: they move with the BLAS kernels.)"""
    from hydroilqr.model.plant import SimulationError

    task = Task.load("cartpole-wall", ["num_steps=20", "solver.max_iterations=4"])
    dyn, s = task.dynamics, task.config.solver
    caps, real = [0.05, 0.05, 1.0, 1.0], dyn.closed_loop_rollout
    it = [0]

    def capped(x0, U, X, K, kappa, eps):
        if eps > caps[it[0]]:
            raise SimulationError("forced rejection")
        return real(x0, U, X, K, kappa, eps)

    def count(info):
        it[0] = min(info.iteration, len(caps) - 1)

    monkeypatch.setattr(dyn, "closed_loop_rollout", capped)
    sol = solve(task, callbacks=[count])
    assert sol.eps[:2] == [1 / 32, 1 / 32] and sol.eps[2] == 1.0, sol.eps
    mus = [s.regularization_init, *sol.mu]
    for i, e in enumerate(sol.eps):
        if e < s.short_step:  # the quadratic model held only for a short step: μ goes up
            assert mus[i + 1] == max(mus[i], s.regularization_min) * s.regularization_factor
        else:
            assert mus[i + 1] == max(s.regularization_min, mus[i] / s.regularization_factor)
    assert mus[2] > mus[1] > mus[0] and mus[3] < mus[2]


def test_nominal_time_horizon_end_aims_every_step_at_the_horizon_end():
    from hydroilqr.model.cost import QuadraticCost
    from hydroilqr.model.state import Block

    layout = StateLayout(1, 1, [Block("p", (0,), (0,)), Block("p.v", (1,), (1,))], ["f"])
    args = (layout, [1.0, 0.1], [50.0, 5.0], [0.01], np.zeros(2), np.array([2.0, 0.0]), 0.1)
    step, end = QuadraticCost(*args), QuadraticCost(*args, nominal_time="horizon_end")
    N, t0 = 4, 1.0
    np.testing.assert_allclose(step.targets(N, t0)[:, 0], 2.0 * (t0 + 0.1 * np.arange(N + 1)))
    np.testing.assert_allclose(end.targets(N, t0)[:, 0], 2.0 * (t0 + 0.1 * N))
    X, U = np.zeros((N + 1, 2)), np.zeros((N, 1))
    X[:, 0] = 2.0 * (t0 + 0.1 * N)  # sitting at the goal: only horizon_end is satisfied
    assert end.total(X, U, t0) == 0.0 < step.total(X, U, t0)
    assert np.all(end.quadratize(X, U, t0).lx == 0.0)
    task = Task.load("cheetah-trot-1.0", ["cost.nominal_time=horizon_end"], smoke=True)
    assert task.cost.nominal_time == "horizon_end"
    with pytest.raises(ConfigError, match="cost.nominal_time: expected one of step, horizon_end"):
        Task.load("cheetah-trot-1.0", ["cost.nominal_time=end"], smoke=True)


def test_a_solve_whose_steps_all_fail_is_not_called_converged(monkeypatch):
    from hydroilqr.model.plant import SimulationError

    task = Task.load("cartpole-wall", ["num_steps=20", "solver.max_iterations=3"])
    ref = solve(task, settings={"max_iterations": 1})  # gains of a normal first iteration
    dyn = task.dynamics

    def fail(*args, **kwargs):
        raise SimulationError("every trial fails")

    monkeypatch.setattr(dyn, "closed_loop_rollout", fail)
    sol = solve(task)
    # Raising μ after each failed search shrinks the predicted decrease below the tolerance:
    # that is not a stationary point.
    assert sol.reason == "line_search_failed" and not sol.converged
    # The gains returned are those at the iteration's own μ (real feedback), not those of the
    # most-regularized retry (max |K| ~ 1e-6).
    assert np.abs(sol.K).max() > 1e-2 * np.abs(ref.K).max() > 0


def test_stopping_in_a_continuation_stage_keeps_feedback_gains():
    task = Task.load(
        "cartpole-wall",
        ["num_steps=20", "solver.max_iterations=5"],
    ).with_overrides({"continuation": [{"tip.hydroelastic_modulus": 1.0e5}]})
    sol = solve(task, callbacks=[lambda info: info.iteration >= 2])
    assert sol.reason == "callback" and np.abs(sol.K).max() > 0 and np.abs(sol.kappa).max() > 0


def test_returned_gains_are_those_around_the_final_trajectory():
    from hydroilqr.model.derivatives import linearize

    task = Task.load("cartpole-wall", ["num_steps=20", "solver.max_iterations=4"])
    sol = solve(task)
    assert sol.eps[-1] > 0
    s = task.config.solver
    # At the smallest workable μ (here Q_uu needs none), not the solver's last μ.
    assert sol.extra["gains_mu"] == s.regularization_min
    A, B = linearize(task.dynamics, sol.X, sol.U, s.derivatives, rollout=True)
    bp = backward_pass(A, B, task.cost.quadratize(sol.X, sol.U, 0.0), s.regularization_min)
    np.testing.assert_allclose(sol.K, bp.K, rtol=1e-9, atol=1e-12)


def test_ctrl_c_during_the_final_gains_keeps_the_solution_unconverged():
    from hydroilqr.model.derivatives import Linearizer

    task = Task.load("cartpole-wall", ["num_steps=20"])
    s = SolverConfig(max_iterations=2, derivatives="forward")
    inner, calls = Linearizer.from_settings(task.dynamics, s), []

    class Interrupting:  # Ctrl+C arrives during the third linearization: the final gains
        last_computed = 0

        def __call__(self, X, U, rollout=True):
            calls.append(1)
            if len(calls) == 3:
                raise KeyboardInterrupt
            out = inner(X, U, rollout=rollout)
            self.last_computed = inner.last_computed
            return out

    sol = ilqr_solve(
        task.problem(), np.zeros((20, 1)), s, linearizer=Interrupting(), stop_on_interrupt=True
    )
    assert sol.reason == "interrupted" and not sol.converged and sol.iterations == 2
