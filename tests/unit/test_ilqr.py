"""solver.ilqr kernels on linear problems: backward pass, LQR in one step, line search."""

import numpy as np
import pytest

from hydroilqr import Task
from hydroilqr.model.cost import Quadratization
from hydroilqr.model.state import StateLayout
from hydroilqr.model.task import Problem
from hydroilqr.problem.solver import SolverConfig
from hydroilqr.solver.ilqr import backward_pass
from hydroilqr.solver.loop import solve as ilqr_solve


def riccati_gains(A, B, Q, R, Qf, N):
    P = Qf
    gains = []
    for _ in range(N):
        K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        P = Q + A.T @ P @ A - A.T @ P @ B @ K
        gains.append(K)
    return gains[::-1]


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


def test_line_search_kernel_accepts_a_descent_step_and_respects_the_deadline():
    import time as _time

    from hydroilqr.model.derivatives import linearize
    from hydroilqr.problem.solver import SolverConfig
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
    warm = line_search(prob, X, U, J, bp.K, bp.kappa, bp.dV, s, None, 0.25)
    assert warm.accepted and warm.eps == 0.25 * s.line_search_factor ** (warm.tried - 1)
    late = line_search(prob, X, U, J, bp.K, bp.kappa, bp.dV, s, _time.perf_counter() - 1)
    assert late.late and not late.accepted and late.tried == 0 and late.X is None
