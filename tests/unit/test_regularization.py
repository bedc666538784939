"""solver.regularization: the final gains are regularized only as Q_uu needs."""

from __future__ import annotations

import numpy as np

from hydroilqr import Task
from hydroilqr.problem.solver import SolverConfig
from hydroilqr.solver import loop
from hydroilqr.solver.regularization import after_step


def test_final_gains_are_regularized_only_as_q_uu_needs():
    """A solve that ends with a large μ (here it starts at 1e3) still returns the feedback of
    eq. (8): the backward pass around the final trajectory at the smallest workable μ, not
    gains shrunk to ~0 by the solver's μ."""
    from hydroilqr.model.derivatives import linearize
    from hydroilqr.solver.ilqr import backward_pass

    task = Task.load(
        "cartpole-wall",
        ["solver.regularization_init=1000", "solver.derivatives=central"],
        smoke=True,
    )
    s = task.config.solver
    for its in (1, 3):
        sol = loop.solve(task.problem(), task.initial_guess(task.steps), s, max_iterations=its)
        assert sol.mu[-1] >= 1.0  # the solver's μ is still large
        assert sol.extra["gains_mu"] == s.regularization_min
        A, B = linearize(task.dynamics, sol.X, sol.U, "central", s.fd_epsilon)
        bp = backward_pass(A, B, task.cost.quadratize(sol.X, sol.U), s.regularization_min)
        np.testing.assert_allclose(sol.K, bp.K, rtol=1e-6, atol=1e-9)


def test_a_short_step_raises_mu_only_when_longer_steps_were_rejected():
    s = SolverConfig()  # short_step 0.1, factor 10
    assert after_step(1e-3, 1 / 16, s, shortened=True) == 1e-2  # the model held only briefly
    assert after_step(1e-3, 1 / 16, s, shortened=False) == 1e-3  # first trial: no evidence
    assert after_step(1e-3, 0.5, s, shortened=True) == 1e-4
    assert after_step(1e-3, 0.5, s, shortened=False) == 1e-4


def test_warm_started_line_search_starts_one_factor_above_the_last_accepted_step(monkeypatch):
    """With solver.line_search_warm_start, each search starts at min(1, ε_prev / f) after an
    iteration that accepted ε_prev, at 1 otherwise; without it, always at 1."""
    firsts = []
    real = loop.line_search

    def recording(*args):
        firsts.append(args[-1])
        return real(*args)

    monkeypatch.setattr(loop, "line_search", recording)
    for warm in (False, True):
        firsts.clear()
        task = Task.load(
            "cartpole-wall",
            [
                f"solver.line_search_warm_start={str(warm).lower()}",
                "solver.derivatives=central",
                "num_steps=50",  # (contact within 0.5 s: short steps taken)
            ],
            smoke=True,
        )
        s = task.config.solver
        sol = loop.solve(task.problem(), task.initial_guess(task.steps), s, max_iterations=6)
        assert len(firsts) >= len(sol.eps)
        if not warm:
            assert set(firsts) == {1.0}
            continue
        # the first search of each iteration (retries at a larger μ start at the same ε)
        expected, prev = [], 0.0
        for e in sol.eps:
            expected.append(min(1.0, prev / s.line_search_factor) if prev > 0 else 1.0)
            prev = e
        assert firsts[0] == 1.0
        assert sorted(set(firsts)) == sorted(set(expected))
        assert any(f < 1.0 for f in firsts)  # the smoke solve does take short steps
