"""solver.solution: saving, loading and refusing Solution files."""

from __future__ import annotations

import numpy as np
import pytest

from hydroilqr.problem.errors import ConfigError


def test_solution_save_load_round_trip_keeps_every_field(tmp_path):
    from hydroilqr.solver.solution import Solution

    N, nx, nu = 3, 2, 1
    rng = np.random.default_rng(0)
    sol = Solution(
        X=rng.standard_normal((N + 1, nx)), U=rng.standard_normal((N, nu)),
        K=rng.standard_normal((N, nu, nx)), kappa=rng.standard_normal((N, nu)),
        t=0.1 * np.arange(N + 1), costs=np.array([3.0, 2.0, 1.5]),
        iteration_seconds=[0.25, 0.5],
        phase_seconds={"rollout": [0.1, 0.2], "derivatives": [0.1, 0.2],
                       "backward_pass": [0.0, 0.05], "line_search": [0.05, 0.05]},
        converged=True, reason="relative_cost", derivatives="autodiff",
        eps=[1.0, 0.5], mu=[1e-6, 1e-7], extra={"task_initial_cost": 9.0, "resolves": [{"a": 1}]},
    )  # fmt: skip
    path = sol.save(tmp_path / "plan.v2")  # a dotted name: .npz appended, not substituted
    assert path == tmp_path / "plan.v2.npz"
    back = Solution.load(tmp_path / "plan.v2")
    for k in ("X", "U", "K", "kappa", "t", "costs"):
        np.testing.assert_array_equal(getattr(back, k), getattr(sol, k))
    for k in ("iteration_seconds", "phase_seconds", "converged", "reason", "derivatives",
              "eps", "mu", "extra"):  # fmt: skip
        assert getattr(back, k) == getattr(sol, k), k
    assert back.stats() == sol.stats()
    assert sol.stats()["initial_cost"] == 9.0  # a continuation's task-model cost
    assert sol.total_seconds == 0.75
    # A plan saved without gains (final_gains=False) loads too.
    bare = Solution(sol.X, sol.U, np.zeros(0), np.zeros(0), sol.t, sol.costs, [], {}, False, "", "")
    bare.save(tmp_path / "bare.npz")
    assert Solution.load(tmp_path / "bare.npz").K.shape == (0,)
    # Gains of the wrong shape are refused.
    bad = Solution(sol.X, sol.U, np.zeros((N, nu, nx + 1)), sol.kappa, sol.t, sol.costs, [], {},
                   False, "", "")  # fmt: skip
    bad.save(tmp_path / "bad.npz")
    with pytest.raises(ValueError, match="arrays disagree"):
        Solution.load(tmp_path / "bad.npz")


def test_an_existing_file_is_loaded_as_given_not_its_npz_sibling(tmp_path):
    from hydroilqr.io.rundir import solution_file

    (tmp_path / "plan").write_bytes(b"x")
    (tmp_path / "plan.npz").write_bytes(b"y")
    assert solution_file(tmp_path / "plan") == tmp_path / "plan"
    assert solution_file(tmp_path / "other") == tmp_path / "other"
    (tmp_path / "other.npz").write_bytes(b"z")
    assert solution_file(tmp_path / "other") == tmp_path / "other.npz"


def test_absurd_lengths_and_non_finite_saved_plans_are_refused(tmp_path):
    import numpy as np

    from hydroilqr.control.mpc import check_settings
    from hydroilqr.model.task import Task
    from hydroilqr.problem.load import load_task
    from hydroilqr.problem.mpc import MPCConfig
    from hydroilqr.solver.solution import Solution

    for bad in (["horizon=2e6"], ["num_steps=20000000"]):
        with pytest.raises(ConfigError, match="at most 1000000"):
            load_task("cartpole-wall", bad)  # it would allocate and run for ever
    with pytest.raises(ConfigError, match="receding_horizon: .* more than 1000000"):
        load_task("cheetah-trot-1.0", ["receding_horizon.resolves=10000000"])
    task = Task.load("cartpole-wall", smoke=True)
    with pytest.raises(ConfigError, match="mpc horizon 1e\\+06 s: more than"):
        check_settings(MPCConfig(horizon=1e6), task)
    from hydroilqr.solver.api import solve

    sol = solve(task.with_overrides({"solver.max_iterations": 1}))
    sol.U[3, 0] = np.nan
    p = sol.save(tmp_path / "plan")
    with pytest.raises(ValueError, match="its U holds non-finite"):
        Solution.load(p)


def test_run_files_that_disagree_are_refused(tmp_path):
    from hydroilqr.solver.solution import Solution, load_run_solution

    def make(n_u):  # a solution of N = 4 steps whose U has n_u rows
        N, nx, nu = 4, 2, 1
        z = np.zeros
        return Solution(
            z((N + 1, nx)), z((n_u, nu)), z((N, nu, nx)), z((N, nu)), np.arange(N + 1.0),
            z(1), [], {}, True, "", "",
        )  # fmt: skip

    make(4).save(tmp_path / "a")
    Solution.load(tmp_path / "a.npz").check_shapes()
    bad = make(2)
    bad.save(tmp_path / "b")
    with pytest.raises(ConfigError, match="arrays disagree"):
        load_run_solution(tmp_path / "b.npz", "cost.reference")
    (tmp_path / "c.npz").write_bytes(b"garbage")
    with pytest.raises(ValueError, match="not a file written by Solution.save"):
        Solution.load(tmp_path / "c.npz")


def test_loading_a_run_directory_killed_during_its_commit_completes_the_commit(tmp_path):
    """Issue 39: a run killed between retiring the old set and installing the new one held no
    solution.npz, and Solution.load failed; the reader now completes the commit first."""
    import json

    from hydroilqr.io import rundir
    from hydroilqr.solver.solution import Solution

    z = np.zeros
    sol = Solution(z((3, 2)), np.ones((2, 1)), z((2, 1, 2)), z((2, 1)), 0.1 * np.arange(3),
                   np.array([2.0, 1.0]), [0.1], {}, True, "x", "central")  # fmt: skip
    out = tmp_path / "run"
    (out / rundir.STAGE).mkdir(parents=True)
    (out / rundir.PREVIOUS).mkdir()
    sol.save(out / rundir.STAGE / "solution.npz")  # the new set, staged
    (out / rundir.PREVIOUS / "solution.npz").write_text("old")  # the old one, retired
    plan = {"retire": ["solution.npz"], "install": ["solution.npz"]}
    (out / rundir.JOURNAL).write_text(json.dumps(plan))
    back = Solution.load(out)
    np.testing.assert_array_equal(back.U, sol.U)
    assert not (out / rundir.JOURNAL).exists() and not (out / rundir.PREVIOUS).exists()
