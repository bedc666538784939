"""Worker processes (model.workers): autodiff and line search in a pool agree with serial."""

from __future__ import annotations

import numpy as np

from hydroilqr import Task, linearize
from hydroilqr.model.task import Problem
from hydroilqr.solver.loop import solve as ilqr_solve


def test_line_search_rounds_go_to_the_workers_and_stop_at_max_steps(monkeypatch):
    """Rounds of two trials (as with line_search_workers=2): sent together, the first acceptable
    one taken (bitwise the serial iterates), and never more trials than line_search_max_steps."""
    from hydroilqr.model import workers
    from hydroilqr.model.plant import SimulationError
    from hydroilqr.solver.loop import solve as ilqr_solve

    task = Task.load("cartpole-wall", ["num_steps=20", "solver.max_iterations=3"])
    dyn = task.dynamics
    problem, U0 = task.problem(), task.initial_guess(task.steps)
    serial = ilqr_solve(problem, U0, task.config.solver)

    rounds = []

    def side_by_side(dyn, x0, U, X, K, kappa, eps_list):  # computed here, recorded
        rounds.append(list(eps_list))
        out = []
        for e in eps_list:
            try:
                out.append(dyn.closed_loop_rollout(x0, U, X, K, kappa, e))
            except SimulationError as err:
                out.append(err)
        return out

    monkeypatch.setattr(workers, "line_search_width", lambda dyn, requested: 2)
    monkeypatch.setattr(workers, "closed_loop_rollouts", side_by_side)
    par = ilqr_solve(problem, U0, task.config.solver)
    assert rounds and all(len(r) == 2 for r in rounds)
    np.testing.assert_array_equal(par.costs, serial.costs)
    assert par.eps == serial.eps

    def reject_all(dyn, x0, U, X, K, kappa, eps_list):
        rounds.append(list(eps_list))
        return [SimulationError("rejected") for _ in eps_list]

    def reject_one(x0, U, X, K, kappa, eps):  # a round of one trial runs here
        rounds.append([eps])
        raise SimulationError("rejected")

    rounds.clear()
    monkeypatch.setattr(workers, "closed_loop_rollouts", reject_all)
    monkeypatch.setattr(dyn, "closed_loop_rollout", reject_one)
    s = task.config.solver
    s.line_search_max_steps, s.line_search_retries, s.max_iterations = 3, 0, 1
    ilqr_solve(problem, U0, s)
    assert rounds == [[1.0, 0.5], [0.25]]  # 3 trials: ε, ε·f in one round, ε·f² alone


def test_a_trial_that_blows_up_in_a_worker_keeps_the_pool():
    from hydroilqr.model import workers
    from hydroilqr.model.plant import SimulationError

    task = Task.load("cartpole-wall", ["solver.line_search_workers=2"], smoke=True)
    dyn = task.dynamics
    N = 10
    U, X = np.zeros((N, dyn.nu)), dyn.rollout(task.x0, np.zeros((N, dyn.nu)))
    K, kappa = np.zeros((N, dyn.nu, dyn.nx)), np.full((N, dyn.nu), -1e12)
    workers.warm_up(dyn, 2)
    out = workers.closed_loop_rollouts(dyn, task.x0, U, X, K, kappa, [0.0, 1.0])
    np.testing.assert_array_equal(out[0][0], X)  # ε = 0: the nominal itself, from a worker
    assert isinstance(out[1], SimulationError)
    assert workers.pool(dyn, 2) is not None and workers.line_search_width(dyn, 2) == 2


def test_worker_processes_exit_when_their_parent_is_killed(tmp_path):
    """kill -9 of a solve must not leave its worker processes (each holding a plant) behind."""
    import os
    import signal
    import subprocess
    import sys
    import time

    script = tmp_path / "pool.py"
    script.write_text(
        "import sys, time\n"
        "from hydroilqr import Task\nfrom hydroilqr.model import workers\n"
        "task = Task.load('kinova-forward', ['solver.autodiff_workers=2'], smoke=True)\n"
        "workers.warm_up(task.dynamics, 2)\n"
        "pool = workers.pool(task.dynamics, 2)\n"
        "print(' '.join(str(p) for p in pool._processes), flush=True)\n"
        "time.sleep(600)\n"
    )
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        pids = [int(p) for p in proc.stdout.readline().split()]
        assert pids
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()

    def alive(pid: int) -> bool:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        # a zombie child of init counts as gone
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"

    deadline = time.time() + 20
    while any(alive(p) for p in pids) and time.time() < deadline:
        time.sleep(0.2)
    assert not any(alive(p) for p in pids)


def test_autodiff_in_worker_processes_equals_serial():
    from hydroilqr.model import workers

    task = Task.load("cartpole-wall")
    dyn = task.dynamics
    U = np.linspace(-3, 3, 12)[:, None]
    X = dyn.rollout(np.array([-0.05, 3.5, 0.0, 0.0]), U)
    workers.warm_up(dyn, 2)
    sent = []
    real_submit = workers._submit
    workers._submit = lambda *a: sent.append(a[1]) or real_submit(*a)
    try:
        A_par, B_par = linearize(dyn, X, U, "autodiff", autodiff_workers=2)
    finally:
        workers._submit = real_submit
    assert sent == [workers._autodiff]  # half the steps went to the other process
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
    test_a_trial_that_blows_up_in_a_worker_keeps_the_pool.)"""
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
        workers.warm_up(dyn, w)  # (else the first rounds run here while the processes start)
        problem = Problem(dyn, task.cost, task.x0)
        sols.append(ilqr_solve(problem, task.initial_guess(task.steps), task.config.solver))
    par, ser = sols
    assert len(par.costs) > 2 and par.costs[-1] < par.costs[0]
    np.testing.assert_array_equal(par.costs, ser.costs)
    assert par.eps == ser.eps
    np.testing.assert_array_equal(par.X, ser.X)
    np.testing.assert_array_equal(par.K, ser.K)


def test_work_is_computed_here_until_the_worker_processes_have_started(monkeypatch):
    """A new pool's processes take about a second to import Drake and build their plants: the
    first partials and trials are computed in this process meanwhile (the same numbers), and
    go to the processes once they are up."""
    from hydroilqr.model import workers

    task = Task.load("cartpole-wall")
    dyn = task.dynamics
    U = np.linspace(-3, 3, 12)[:, None]
    X = dyn.rollout(np.array([-0.05, 3.5, 0.0, 0.0]), U)
    A_ser, B_ser = linearize(dyn, X, U, "autodiff")
    workers.pool(dyn, 2)
    assert not workers.started(dyn)  # the process is importing Drake
    sent = []
    real_submit = workers._submit
    monkeypatch.setattr(workers, "_submit", lambda *a: sent.append(a[1]) or real_submit(*a))
    A, B = workers.autodiff(dyn, X, U, 2)
    assert sent == []  # all computed here
    np.testing.assert_array_equal(A, A_ser)
    np.testing.assert_array_equal(B, B_ser)
    workers.warm_up(dyn, 2)
    assert workers.started(dyn)
    A, B = workers.autodiff(dyn, X, U, 2)
    assert sent == [workers._autodiff]
    np.testing.assert_array_equal(A, A_ser)
    np.testing.assert_array_equal(B, B_ser)
