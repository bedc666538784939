"""solver.regularization: the final gains are regularized only as Q_uu needs."""

from __future__ import annotations

import numpy as np

from hydroilqr import Task


def test_final_gains_are_regularized_only_as_q_uu_needs():
    """A solve that ends with a large μ (here it starts at 1e3) still returns the feedback of
    eq. (8): the backward pass around the final trajectory at the smallest workable μ, not
    gains shrunk to ~0 by the solver's μ."""
    from hydroilqr.model.derivatives import linearize
    from hydroilqr.solver.ilqr import backward_pass
    from hydroilqr.solver.loop import solve

    task = Task.load(
        "cartpole-wall",
        ["solver.regularization_init=1000", "solver.derivatives=central"],
        smoke=True,
    )
    s = task.config.solver
    for its in (1, 3):
        sol = solve(task.problem(), task.initial_guess(task.steps), s, max_iterations=its)
        assert sol.mu[-1] >= 1.0  # the solver's μ is still large
        assert sol.extra["gains_mu"] == s.regularization_min
        A, B = linearize(task.dynamics, sol.X, sol.U, "central", s.fd_epsilon)
        bp = backward_pass(A, B, task.cost.quadratize(sol.X, sol.U), s.regularization_min)
        np.testing.assert_allclose(sol.K, bp.K, rtol=1e-6, atol=1e-9)
