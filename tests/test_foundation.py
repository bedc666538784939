"""Foundation: LQR = Riccati, derivatives agree, the plant really steps, cart-pole solves."""

import json

import numpy as np
import pytest

from hydroilqr import DerivativeMethod, Task, linearize, solve
from hydroilqr.model.cost import Quadratization
from hydroilqr.model.state import StateLayout
from hydroilqr.problem.config import ConfigError, SolverConfig
from hydroilqr.solver.ilqr import Problem, backward_pass
from hydroilqr.solver.ilqr import solve as ilqr_solve


def riccati_gains(A, B, Q, R, Qf, N):
    P = Qf
    gains = []
    for _ in range(N):
        K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        P = Q + A.T @ P @ A - A.T @ P @ B @ K
        gains.append(K)
    return gains[::-1]


def test_backward_pass_equals_riccati():
    rng = np.random.default_rng(0)
    nx, nu, N = 4, 2, 25
    A = np.eye(nx) + 0.1 * rng.standard_normal((nx, nx))
    B = rng.standard_normal((nx, nu))
    Q, R, Qf = np.diag([1.0, 2.0, 0.5, 0.1]), np.diag([0.3, 0.7]), 10 * np.eye(nx)
    quad = Quadratization(
        lx=np.zeros((N + 1, nx)),
        lxx=np.stack([2 * Q] * N + [2 * Qf]),
        lu=np.zeros((N, nu)),
        luu=np.stack([2 * R] * N),
    )
    bp = backward_pass(np.stack([A] * N), np.stack([B] * N), quad, mu=0.0)
    assert bp.ok
    for k, K in enumerate(riccati_gains(A, B, Q, R, Qf, N)):
        np.testing.assert_allclose(bp.K[k], K, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(bp.kappa, 0.0, atol=1e-14)


class LinearDynamics:
    """x+ = A x + B u, duck-typed like plant.Dynamics for the solver."""

    def __init__(self, A, B):
        self.A, self.B = A, B
        self.nx, self.nu, self.dt = A.shape[0], B.shape[1], 0.1

    def step(self, x, u):
        return self.A @ x + self.B @ u

    def rollout(self, x0, U):
        X = [x0]
        for u in U:
            X.append(self.step(X[-1], u))
        return np.array(X)

    def closed_loop_rollout(self, x0, Ubar, Xbar, K, kappa, eps):
        X, U = [x0], []
        for k in range(len(Ubar)):
            U.append(Ubar[k] - eps * kappa[k] - K[k] @ (X[-1] - Xbar[k]))
            X.append(self.step(X[-1], U[-1]))
        return np.array(X), np.array(U)


def test_ilqr_solves_lqr_in_one_step():
    """On a linear system with quadratic cost, the first full iLQR step is optimal."""
    from hydroilqr.model.cost import QuadraticCost
    from hydroilqr.model.state import Block

    rng = np.random.default_rng(1)
    nx, nu, N = 2, 1, 30
    A = np.array([[1.0, 0.1], [0.0, 1.0]])
    B = np.array([[0.005], [0.1]])
    dyn = LinearDynamics(A, B)

    class ExactPartials:  # the system's own A, B (a Linearizer stand-in)
        last_computed = N

        def __call__(self, X, U, rollout=True):
            return np.stack([A] * N), np.stack([B] * N)

    layout = StateLayout(1, 1, [Block("p", (0,), (0,)), Block("p.v", (1,), (1,))], ["f"])
    cost = QuadraticCost(layout, [1.0, 0.1], [50.0, 5.0], [0.01], np.zeros(2), np.zeros(2), 0.1)
    x0 = np.array([1.0, 0.0])
    sol = ilqr_solve(
        Problem(dyn, cost, x0),
        rng.standard_normal((N, nu)),
        SolverConfig(max_iterations=5, regularization_init=0.0, regularization_min=0.0),
        linearizer=ExactPartials(),
    )
    # Closed-form optimum: stack the LQR as a least-squares problem in U.
    Phi = np.zeros((N + 1, nx, N * nu))
    Ak = np.eye(nx)
    free = [x0]
    for k in range(1, N + 1):
        Phi[k] = A @ Phi[k - 1]
        Phi[k][:, (k - 1) * nu : k * nu] += B[:, :]
        Ak = A @ Ak
        free.append(Ak @ x0)
    free = np.array(free)
    W = [np.diag([1.0, 0.1])] * N + [np.diag([50.0, 5.0])]
    H = 0.01 * np.eye(N * nu)
    g = np.zeros(N * nu)
    for k in range(N + 1):
        H += Phi[k].T @ W[k] @ Phi[k]
        g += Phi[k].T @ W[k] @ free[k]
    U_opt = -np.linalg.solve(H, g)
    J_opt = float(g @ U_opt + sum(free[k] @ W[k] @ free[k] for k in range(N + 1)))
    np.testing.assert_allclose(sol.U.ravel(), U_opt, rtol=1e-6, atol=1e-8)
    assert sol.converged
    # One step: the first iteration takes the full step and lands on the optimum; the next
    # predicts no decrease and stops there.
    assert sol.eps[0] == 1.0 and sol.iterations <= 2
    assert sol.costs[0] > 2 * J_opt
    assert sol.costs[1] == pytest.approx(J_opt, rel=1e-9)
    # The returned feedback is the LQR policy: Riccati gains, no feedforward left at the optimum.
    Q, Qf, R = np.diag([1.0, 0.1]), np.diag([50.0, 5.0]), np.array([[0.01]])
    np.testing.assert_allclose(sol.K, riccati_gains(A, B, Q, R, Qf, N), rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(sol.kappa, 0.0, atol=1e-8)


@pytest.fixture(scope="module")
def cartpole():
    return Task.load("cartpole-wall")


def test_autodiff_matches_central_differences_in_and_out_of_contact(cartpole):
    dyn = cartpole.dynamics
    # Out of contact, then the tip pressed ~3 mm into the wall (generic, non-symmetric poses).
    free = np.array([0.013, 3.52, -0.21, 0.37])
    theta = np.pi + np.arcsin((0.45 - 0.05 + 0.003 - 0.011) / 0.5)
    touching = np.array([-0.011, theta, -0.05, 0.12])
    assert not dyn.contact_surfaces(free)
    assert dyn.contact_surfaces(touching), "the tip should touch the wall"
    X = np.stack([free, touching, touching])
    U = np.array([[1.3], [-2.1], [0.7]])
    A_ad, B_ad = linearize(dyn, X, U, DerivativeMethod.AUTODIFF)
    A_fd, B_fd = linearize(dyn, X, U, DerivativeMethod.CENTRAL)
    for k in range(2):
        J_ad = np.hstack([A_ad[k], B_ad[k]])
        J_fd = np.hstack([A_fd[k], B_fd[k]])
        err = np.max(np.abs(J_ad - J_fd)) / np.max(np.abs(J_ad))
        assert err < 1e-4, f"step {k}: relative error {err:.2e}"
    # Contact changes the partials (the wall is felt).
    assert np.max(np.abs(A_ad[1] - A_ad[0])) > 1e-3


def test_forward_differences_close_to_autodiff(cartpole):
    dyn = cartpole.dynamics
    X = np.array([[0.02, 3.3, 0.1, -0.2]])
    U = np.array([[0.5]])
    A_ad, B_ad = linearize(dyn, X, U, "autodiff")
    A_fw, B_fw = linearize(dyn, X, U, "forward")
    assert np.max(np.abs(A_ad - A_fw)) / np.max(np.abs(A_ad)) < 1e-4
    assert np.max(np.abs(B_ad - B_fw)) / np.max(np.abs(B_ad)) < 1e-4


def test_falling_body_falls(tmp_path):
    """A discrete plant's step must really advance (drake-notes: sampled-output-port trap)."""
    from hydroilqr.problem.config import TASKS_DIR

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


def test_quaternion_difference_jacobian():
    from hydroilqr.model.state import Block

    layout = StateLayout(
        7,
        6,
        [
            Block("b.orientation", (0, 1, 2, 3), (0, 1, 2), "quaternion"),
            Block("b.position", (4, 5, 6), (3, 4, 5)),
            Block("b.angular_velocity", (7, 8, 9), (6, 7, 8)),
            Block("b.velocity", (10, 11, 12), (9, 10, 11)),
        ],
        [],
    )
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.standard_normal(4), rng.standard_normal(3), rng.standard_normal(6)])
    x[:4] /= np.linalg.norm(x[:4])
    ref = layout.normalize(x + 0.1 * rng.standard_normal(13))
    J = layout.diff_jacobian(x[None], ref[None])[0]
    h = 1e-7
    Jn = np.stack(
        [(layout.diff(x + h * e, ref) - layout.diff(x - h * e, ref)) / (2 * h) for e in np.eye(13)],
        axis=1,
    )
    np.testing.assert_allclose(J, Jn, atol=1e-6)
    # A rotation of angle a about z gives an error of (0, 0, ~a).
    a = 0.2
    q = np.array([np.cos(a / 2), 0, 0, np.sin(a / 2)])
    xq = np.concatenate([q, np.zeros(9)])
    ident = np.concatenate([[1.0, 0, 0, 0], np.zeros(9)])
    np.testing.assert_allclose(layout.diff(xq, ident)[:3], [0, 0, 2 * np.sin(a / 2)])


def _reference_quadratization(cost, X, U, t0):
    """The cost derivatives from the definitions, densely: l_x = 2 Jrᵀ W r, l_xx = 2 Jrᵀ W Jr
    (r = x ⊖ x_nom, Jr = ∂r/∂x from diff_jacobian), l_u = 2 R u, l_uu = 2 R."""
    N = U.shape[0]
    Xn = cost.targets(N, t0)
    r = cost.layout.diff(X, Xn)
    Jr = cost.layout.diff_jacobian(X, Xn)
    W = np.array([cost.q] * N + [cost.qf])
    lx = np.stack([2 * Jr[k].T @ (W[k] * r[k]) for k in range(N + 1)])
    lxx = np.stack([2 * Jr[k].T @ np.diag(W[k]) @ Jr[k] for k in range(N + 1)])
    return lx, lxx, 2 * U * cost.r, np.stack([2 * np.diag(cost.r)] * N)


@pytest.mark.parametrize("quaternion", [False, True])
def test_quadratize_equals_the_dense_reference(quaternion):
    """Both paths of QuadraticCost.quadratize (the coordinate permutation when there are no
    quaternions, the Jacobian einsum otherwise) against the dense formulas."""
    from hydroilqr.model.cost import QuadraticCost
    from hydroilqr.model.state import Block

    if quaternion:
        blocks = [
            Block("b.orientation", (0, 1, 2, 3), (0, 1, 2), "quaternion"),
            Block("b.position", (4, 5, 6), (3, 4, 5)),
            Block("b.angular_velocity", (7, 8, 9), (6, 7, 8)),
            Block("b.velocity", (10, 11, 12), (9, 10, 11)),
        ]
        layout = StateLayout(7, 6, blocks, ["a", "b"])
    else:  # tangent order differs from coordinate order by 3-cycles: the permutation matters
        blocks = [
            Block("p", (2, 0, 1), (0, 1, 2)),
            Block("p.v", (3, 4, 5), (4, 5, 3)),
        ]
        layout = StateLayout(3, 3, blocks, ["a", "b"])
    rng = np.random.default_rng(7)
    nx, nt, N = layout.nx, 2 * layout.nv, 6
    X = rng.standard_normal((N + 1, nx))
    if quaternion:
        X = layout.normalize(X)
    U = rng.standard_normal((N, 2))
    x_nom = layout.normalize(rng.standard_normal(nx)) if quaternion else rng.standard_normal(nx)
    rate = np.zeros(nx)
    rate[4 if quaternion else 0] = 0.3  # a moving nominal on a euclidean coordinate
    cost = QuadraticCost(
        layout, rng.uniform(0.1, 2, nt), rng.uniform(1, 5, nt), [0.2, 0.7], x_nom, rate, 0.1
    )
    quad = cost.quadratize(X, U, t0=0.4)
    for got, want in zip(
        (quad.lx, quad.lxx, quad.lu, quad.luu), _reference_quadratization(cost, X, U, 0.4)
    ):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


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


def test_overrides_and_shortcuts():
    task = Task.load(
        "cartpole-wall",
        ["tip.hydroelastic_modulus=3e5", "wall.friction=0.1", "solver.max_iterations=7"],
    )
    assert task.config.geometry["tip"].hydroelastic_modulus == 3e5
    assert task.config.scene[0].friction == 0.1
    assert task.config.solver.max_iterations == 7


def test_cli_solve_writes_outputs(tmp_path):
    import json

    from hydroilqr.cli import main

    out = tmp_path / "run"
    assert (
        main(
            [
                "solve",
                "cartpole-wall",
                "--smoke",
                "--set",
                "solver.max_iterations=2",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    summary = json.loads((out / "summary.json").read_text())
    for key in (
        "task",
        "converged",
        "iterations",
        "final_cost",
        "iteration_seconds",
        "phase_seconds",
        "derivatives",
        "metrics",
    ):
        assert key in summary
    for key in ("final_angle_error_rad", "max_overlap_m", "wall_contact_steps"):
        assert key in summary["metrics"]
    for f in ("solution.npz", "convergence.png", "replay.html"):
        assert (out / f).stat().st_size > 0
    assert "<html" in (out / "replay.html").read_text()[:2000].lower()


def test_autodiff_in_worker_processes_equals_serial():
    from hydroilqr.model import workers

    task = Task.load("cartpole-wall")
    dyn = task.dynamics
    U = np.linspace(-3, 3, 12)[:, None]
    X = dyn.rollout(np.array([-0.05, 3.5, 0.0, 0.0]), U)
    A_par, B_par = linearize(dyn, X, U, "autodiff", autodiff_workers=2)
    assert workers.pool_size(dyn) == 2  # the processes were used
    A_ser, B_ser = linearize(dyn, X, U, "autodiff")
    np.testing.assert_array_equal(A_par, A_ser)
    np.testing.assert_array_equal(B_par, B_ser)


def test_solve_uses_the_worker_counts_of_its_settings_not_the_tasks():
    """ilqr.solve(problem, U0, settings) sizes its worker processes from ``settings``
    (the task's own solver section says 1 here) and gives the serial iterates."""
    import dataclasses

    from hydroilqr.model import workers

    task = Task.load("cartpole-wall", ["solver.max_iterations=2"], smoke=True)
    assert task.config.solver.autodiff_workers == task.config.solver.line_search_workers == 1
    s = dataclasses.replace(
        task.config.solver, derivatives="autodiff", autodiff_workers=2, line_search_workers=2
    )
    U0 = task.initial_guess(task.steps)
    par = ilqr_solve(Problem(task.dynamics, task.cost, task.x0), U0, s)
    assert workers.pool_size(task.dynamics) == 2
    serial = Task.load("cartpole-wall", ["solver.max_iterations=2"], smoke=True)
    s1 = dataclasses.replace(s, autodiff_workers=1, line_search_workers=1)
    ser = ilqr_solve(Problem(serial.dynamics, serial.cost, serial.x0), U0, s1)
    assert workers.pool_size(serial.dynamics) == 1
    np.testing.assert_array_equal(par.X, ser.X)
    np.testing.assert_array_equal(par.costs, ser.costs)


def test_line_search_in_worker_processes_equals_serial():
    """Trials side by side in two processes give bitwise the serial iterates. (Three smoke
    iterations take steps of 1/4 to 1/32: rounds past the first. A trial blowing up in a worker:
    test_edges::test_a_trial_that_blows_up_in_a_worker_keeps_the_pool.)"""
    from hydroilqr.model import workers

    sols = []
    for w in (2, 1):
        task = Task.load(
            "cartpole-wall",
            [f"solver.line_search_workers={w}", "solver.max_iterations=3"],
            smoke=True,
        )
        dyn = task.dynamics
        assert workers.line_search_width(dyn, w) == w
        problem = Problem(dyn, task.cost, task.x0)
        sols.append(ilqr_solve(problem, task.initial_guess(task.steps), task.config.solver))
    par, ser = sols
    assert len(par.costs) > 2 and par.costs[-1] < par.costs[0]
    np.testing.assert_array_equal(par.costs, ser.costs)
    assert par.eps == ser.eps
    np.testing.assert_array_equal(par.X, ser.X)
    np.testing.assert_array_equal(par.K, ser.K)


def test_blown_up_step_is_a_simulation_error(cartpole):
    """A state that explodes is reported (and rejected by a line search), never returned."""
    from hydroilqr.model.plant import SimulationError

    dyn = cartpole.dynamics
    x = np.zeros(dyn.nx)
    x[-1] = 1e7  # pole spinning at 1e7 rad/s
    with pytest.raises(SimulationError, match="diverged"):
        dyn.step(x, np.zeros(dyn.nu))


def test_cost_reference_tracks_a_solved_run(tmp_path):
    from hydroilqr.problem.config import ConfigError

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


def test_cost_reference_quaternions_are_renormalized():
    from hydroilqr.model.cost import QuadraticCost

    task = Task.load("cheetah-trot-1.0", smoke=True)
    layout = task.dynamics.layout
    X = np.tile(task.x0, (2, 1))
    q = list(layout.quaternions[0].coords)
    a = 0.8
    X[1, q] = [np.cos(a / 2), 0, 0, np.sin(a / 2)]
    cost = task.cost
    assert isinstance(cost, QuadraticCost)
    cost.set_reference(np.array([0.0, 1.0]), X, [])
    mid = cost.nominal(np.array([0.5]))[0, q]
    assert abs(np.linalg.norm(mid) - 1.0) < 1e-12


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


def test_cost_terms_add_up_to_the_cost_when_blocks_overlap():
    task = Task.load(
        "cartpole-wall",
        [
            "num_steps=10",
            "blocks.positions=[cart_slider, pole_pin]",
            "cost.Q={positions: 0.5, pole_angle: 2.0}",
        ],
    )
    X = task.dynamics.rollout(task.x0, np.full((10, 1), 3.0))
    U = np.full((10, 1), 3.0)
    terms = task.cost.breakdown(X, U)
    assert sum(terms.values()) == pytest.approx(task.cost.total(X, U), rel=1e-12)


def test_returned_gains_are_those_around_the_final_trajectory():
    from hydroilqr.model.derivatives import linearize
    from hydroilqr.solver.ilqr import backward_pass

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


def test_package_data_ships_every_task_and_model_file():
    """A non-editable install (pip install .) carries only the files pyproject's package-data
    names: every file the built-in tasks read (models, the cheetah's standing-torque CSV) must
    match one of its patterns."""
    import fnmatch
    import tomllib
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    pkg = root / "src" / "hydroilqr"
    pyproject = tomllib.loads((root / "pyproject.toml").read_text())
    patterns = pyproject["tool"]["setuptools"]["package-data"]["hydroilqr"]
    files = [
        p.relative_to(pkg).as_posix()
        for d in ("tasks", "models")
        for p in (pkg / d).rglob("*")
        if p.is_file() and "__pycache__" not in p.parts
    ]
    assert "tasks/cheetah_standing_torques.csv" in files
    missing = [f for f in files if not any(fnmatch.fnmatch(f, pat) for pat in patterns)]
    assert missing == []


def test_line_search_kernel_accepts_a_descent_step_and_respects_the_deadline():
    import time as _time

    from hydroilqr.model.derivatives import linearize
    from hydroilqr.problem.config import SolverConfig
    from hydroilqr.solver.ilqr import backward_pass, line_search

    task = Task.load("cartpole-wall", ["num_steps=30"])
    prob = task.problem()
    U = task.initial_guess(30)
    X = task.dynamics.rollout(prob.x0, U)
    J = prob.cost.total(X, U, 0.0)
    A, B = linearize(task.dynamics, X, U, "central")
    bp = backward_pass(A, B, prob.cost.quadratize(X, U, 0.0), 1e-6)
    s = SolverConfig()
    ls = line_search(prob, X, U, J, bp.K, bp.kappa, bp.dV, s)
    assert ls.accepted and ls.J < J and ls.tried >= 1 and ls.X.shape == X.shape
    np.testing.assert_allclose(ls.J, prob.cost.total(ls.X, ls.U, 0.0))
    assert ls.eps == s.line_search_factor ** (ls.tried - 1)  # ε = 1, f, f², ...
    late = line_search(prob, X, U, J, bp.K, bp.kappa, bp.dV, s, _time.perf_counter() - 1)
    assert late.late and not late.accepted and late.tried == 0 and late.X is None
