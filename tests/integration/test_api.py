"""The Python API as a researcher uses it from a script or notebook (smoke-sized problems)."""

import subprocess
import sys

import numpy as np
import pytest

from hydroilqr import ConfigError, SimulationError, Solution, SolverConfig, Task, solve
from hydroilqr.metrics import validate_task


@pytest.fixture(scope="module")
def task():
    return Task.load("cartpole-wall", smoke=True, overrides="solver.max_iterations=3")


def _rollout(t):
    U = t.initial_guess(t.steps)
    return t.dynamics.rollout(t.x0, U), U


def test_solve_takes_own_guess_and_state_and_leaves_the_task_alone(task):
    U0 = np.full((task.steps, 1), 0.5)
    x0 = task.x0 + np.array([0.0, 0.01, 0.0, 0.0])
    sol = solve(task, U0=U0, x0=x0, settings=SolverConfig(max_iterations=2))
    assert sol.iterations <= 2
    np.testing.assert_array_equal(sol.X[0], x0)
    assert task.config.solver.max_iterations == 3  # settings were for that solve only
    assert solve("cartpole-wall", settings=SolverConfig(max_iterations=1)).iterations == 1
    # A dict changes only the named fields of the task's own solver section.
    assert solve(task, settings={"max_iterations": 1}).iterations == 1
    with pytest.raises(ConfigError, match="settings.max_iter: unknown key"):
        solve(task, settings={"max_iter": 1})
    with pytest.raises(TypeError, match="settings: expected a SolverConfig or a dict"):
        solve(task, settings=3)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"U0": np.zeros((5, 1))}, r"U0 must have shape \[200, 1\] .*got \(5, 1\)"),
        ({"U0": np.full((200, 1), np.nan)}, r"U0 must be finite .*: U0\[0, 0\] is nan"),
        ({"U0": "zeros"}, "U0 must have shape"),
        ({"x0": np.zeros(3)}, "x0 must have shape"),
        ({"x0": np.array([0.0, np.nan, 0.0, 0.0])}, r"x0 must be finite .*: x0\[1\] is nan"),
    ],
)
def test_bad_guess_or_state_is_a_value_error(task, kwargs, match):
    if isinstance(kwargs.get("U0"), str):
        kwargs = {"U0": np.zeros(task.steps)}  # 1-D
    with pytest.raises(ValueError, match=match):
        solve(task, **kwargs)


def test_bad_settings_and_inputs_give_clear_errors(task):
    with pytest.raises(ConfigError, match="line_search_factor"):
        solve(task, settings=SolverConfig(line_search_factor=2.0))
    with pytest.raises(ConfigError, match="expected one of autodiff"):
        solve(task, settings=SolverConfig(derivatives="autodif"))
    x = task.x0.copy()
    x[1] = np.nan
    with pytest.raises(SimulationError, match="non-finite"):
        task.dynamics.step(x, np.zeros(1))  # Drake's own check would end the process
    with pytest.raises(ValueError, match=r"x must have shape \[4\]"):
        task.dynamics.step(task.x0[:3], np.zeros(1))
    with pytest.raises(ConfigError, match="Task.from_dict"):
        Task.from_yaml("name: x\nmodels: []\n")
    with pytest.raises(ValueError, match="positive"):
        task.initial_guess(-1)


def test_callback_sees_iterates_and_can_stop(task):
    seen = []

    def cb(info):
        seen.append((info.iteration, info.X.shape, info.U.shape))
        return np.int64(info.iteration) >= 2  # a numpy bool stops too

    sol = solve(task.with_overrides({"solver.max_iterations": 10}), callbacks=[cb])
    assert sol.iterations == 2 and sol.reason == "callback" and not sol.converged
    one = solve(task.with_overrides({"solver.max_iterations": 10}), callbacks=cb)  # not a list
    assert one.iterations == 2 and one.reason == "callback"
    with pytest.raises(TypeError, match="callbacks: expected a function .* got list of str"):
        solve(task, callbacks=["print"])
    with pytest.raises(TypeError, match="callbacks: expected a function .* got int"):
        solve(task, callbacks=3)
    from_set = solve(task.with_overrides({"solver.max_iterations": 10}), callbacks={cb})
    assert from_set.iterations == 2  # any iterable of functions, as before
    assert seen[0] == (1, (task.steps + 1, 4), (task.steps, 1))


def test_overrides_make_a_new_task_and_read_1e6_as_a_number(task):
    stiff = task.with_overrides(["cost.Qf.pole_angle=1e6"])
    assert stiff.config.cost.Qf["pole_angle"] == 1e6
    assert task.config.cost.Qf["pole_angle"] != 1e6
    assert stiff.cost.total(*_rollout(stiff)) > task.cost.total(*_rollout(task))


def test_save_and_load_agree_on_paths(task, tmp_path):
    sol = solve(task)
    assert sol.save(tmp_path / "plan") == tmp_path / "plan.npz"
    assert Solution.load(tmp_path / "plan").final_cost == sol.final_cost
    run = tmp_path / "run"
    run.mkdir()
    assert sol.save(run) == run / "solution.npz"
    np.testing.assert_array_equal(Solution.load(run).U, sol.U)
    assert sol.total_seconds >= sum(sum(v) for v in sol.phase_seconds.values()) - 1e-9
    with pytest.raises(FileNotFoundError, match=r"plan.npz'\): no directory .*nodir$"):
        sol.save(tmp_path / "nodir" / "plan")
    # the fields of summary.json are attributes too
    assert sol.initial_cost == sol.costs[0] == sol.stats()["initial_cost"]
    assert Solution.load(run).initial_cost == sol.initial_cost
    # short reprs for a notebook: shapes and the outcome, not every array element
    assert repr(task) == "Task('cartpole-wall', 200 steps of 0.01 s)"
    assert repr(sol).startswith("Solution(X [201, 4], U [200, 1], K [200, 1, 4]")
    assert f"reason={sol.reason!r}" in repr(sol) and len(repr(sol)) < 300


def test_script_without_main_guard_runs_once_with_worker_processes(tmp_path):
    """Worker processes are spawned; they must not run the user's script again."""
    script = tmp_path / "noguard.py"
    script.write_text(
        "print('TOP', flush=True)\n"
        "from hydroilqr import Task, solve\n"
        "t = Task.load('cartpole-wall', smoke=True, overrides=['solver.max_iterations=2',\n"
        "    'solver.derivatives=autodiff', 'solver.autodiff_workers=2',\n"
        "    'solver.line_search_workers=2'])\n"
        "solve(t)\n"
        "assert t.dynamics._worker_pool, 'no worker processes were used'\n"
        "print('DONE', flush=True)\n"
    )
    out = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=300, cwd=tmp_path
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.count("TOP") == 1 and out.stdout.count("DONE") == 1


def test_audit_cases_round_trip_overrides_resolver_and_truthy_callbacks(task):
    from hydroilqr.problem.files import yaml_value

    kin = Task.load("kinova-forward", smoke=True)  # sets num_steps
    again = Task.from_dict(kin.config.to_dict(), base_dir=kin.config.base_dir)
    assert again.steps == kin.steps
    assert kin.with_overrides("solver.max_iterations=2").config.solver.max_iterations == 2
    assert kin.with_overrides({"horizon": 0.2}).steps == 20  # horizon wins, as with --set
    assert yaml_value("1e6") == 1e6 and yaml_value(".5e1") == 5.0
    for text in (".e5", "-e5", "+E1", "v1e3", "0x1e5"):
        assert not isinstance(yaml_value(text), float), text
    calls = []
    three = task.with_overrides({"solver.max_iterations": 3})
    sol = solve(three, callbacks=[lambda i: calls.append(1) or 1])
    assert sol.reason != "callback" and len(calls) == sol.iterations  # 1 is not True


def test_computed_guess_holds_the_given_state():
    kin = Task.load("kinova-forward", smoke=True, overrides=["solver.max_iterations=0"])
    x0 = kin.x0.copy()
    x0[:7] += 0.3
    sol = solve(kin, x0=x0)
    np.testing.assert_allclose(sol.U[0], kin.initial_guess(kin.steps, x=x0)[0])


def test_worker_pools_close_with_their_tasks():
    import gc

    from hydroilqr.model import workers

    base = Task.load("cartpole-wall", smoke=True, overrides=["solver.line_search_workers=2"])
    pools = []
    for _ in range(2):
        t = base.with_overrides({"solver.max_iterations": 1})
        workers.warm_up(t.dynamics, 2)
        pools.append(t.dynamics._worker_pool)
        del t
        gc.collect()
    assert all(p._shutdown_thread for p in pools)


def test_version_names_what_decides_the_last_bits(capsys):
    from hydroilqr import cli

    with pytest.raises(SystemExit) as e:
        cli.main(["--version"])
    out = capsys.readouterr().out
    assert e.value.code == 0 and out.startswith("hydroilqr ") and "OpenBLAS kernels" in out


def test_version_says_unknown_when_git_gives_no_commit(capsys, monkeypatch):
    """Outside a git checkout, or one git refuses (another user's: "dubious ownership")."""
    from hydroilqr import cli
    from hydroilqr.io import environment

    monkeypatch.setattr(environment, "code_version", lambda: "")
    with pytest.raises(SystemExit):
        cli.main(["--version"])
    assert "(code unknown; drake " in capsys.readouterr().out


def test_an_ascii_only_terminal_gets_escapes_not_a_traceback():
    """PYTHONIOENCODING=ascii (or PYTHONUTF8=0 under LANG=C): help texts and check's table
    use ū, x̄ and τ."""
    import os

    env = {**os.environ, "PYTHONIOENCODING": "ascii"}
    for args in (["playback", "--help"], ["check", "cartpole-wall"]):
        r = subprocess.run(
            [sys.executable, "-m", "hydroilqr", *args], env=env, capture_output=True, text=True
        )
        assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert "\\u03c4" in r.stdout  # check's damping column: τ


def test_continuation_stages_warm_start_the_task(task):
    staged = task.with_overrides(
        {"continuation": [{"tip.hydroelastic_modulus": 1.0e5}], "solver.max_iterations": 2}
    )
    assert staged.stages()[0].config.geometry["tip"].hydroelastic_modulus == 1.0e5
    sol = solve(staged)
    st = sol.extra["continuation"]
    assert [s["overrides"] for s in st] == [{"tip.hydroelastic_modulus": 1.0e5}, {}]
    assert sum(s["iterations"] for s in st) == sol.iterations == len(sol.costs) - 1
    assert len(sol.iteration_seconds) == len(sol.phase_seconds["derivatives"]) == sol.iterations
    assert st[0]["final_cost"] <= st[0]["start_cost"] and sol.costs[0] == st[0]["start_cost"]
    # every stage's linearizations (one per iteration, plus each stage's final gains)
    assert len(sol.extra["derivative_steps"]) >= sol.iterations


def test_continuation_is_checked_before_solving():
    with pytest.raises(ConfigError, match="receding_horizon"):
        Task.load("cheetah-trot-1.0", smoke=True, overrides={"continuation": [{"plant.x": 1}]})
    bad = Task.load("cartpole-wall", smoke=True, overrides={"continuation": [{"tipp.friction": 1}]})
    with pytest.raises(ConfigError, match=r"continuation\[0\]"):
        validate_task(bad)


def test_stopping_inside_a_stage_returns_the_task_models_trajectory(task):
    staged = task.with_overrides(
        {"continuation": [{"tip.hydroelastic_modulus": 1.0e5}], "solver.max_iterations": 3}
    )
    sol = solve(staged, callbacks=[lambda info: True])  # stops in the stage, not just the stage
    assert sol.reason == "callback" and sol.iterations == 1
    X = staged.dynamics.rollout(staged.x0, sol.U)
    np.testing.assert_array_equal(sol.X, X)  # the task's model, not the soft stage's
    assert sol.final_cost == pytest.approx(staged.cost.total(X, sol.U))
    solve(staged, settings=SolverConfig(max_iterations=1))
    assert staged.stages()[0].config.solver.max_iterations == 3  # per-call settings do not stick
    with pytest.raises(ConfigError, match="cannot change between stages"):
        task.with_overrides({"continuation": [{"horizon": 0.5}]})


def test_a_worker_dying_during_autodiff_costs_time_not_the_solve(monkeypatch):
    from concurrent.futures.process import BrokenProcessPool

    from hydroilqr.model import workers
    from hydroilqr.model.autodiff import autodiff_serial

    class Dead:  # the future of a chunk whose worker process was killed
        def result(self):
            raise BrokenProcessPool("a process in the pool was terminated abruptly")

    dyn = Task.load("cartpole-wall", overrides="num_steps=8").dynamics
    X = dyn.rollout(dyn.initial_state(), np.zeros((8, 1)))
    U = np.zeros((8, 1))
    workers.warm_up(dyn, 2)
    monkeypatch.setattr(workers, "_submit", lambda *args: Dead())
    A, B = workers.autodiff(dyn, X[:-1], U, 2)
    A0, B0 = autodiff_serial(dyn, X[:-1], U)
    np.testing.assert_array_equal(A, A0)
    np.testing.assert_array_equal(B, B0)
    assert dyn._worker_pool is False  # serial from now on


def test_settings_dict_changes_each_stage_own_solver_section():
    task = Task.load("cartpole-wall", overrides="num_steps=20").with_overrides(
        {"continuation": [{"solver.regularization_init": 0.5, "solver.regularization_min": 0.5}]}
    )
    sol = solve(task, settings={"max_iterations": 1})
    assert sol.iterations == 2  # one per stage
    assert sol.mu[0] >= 0.5 > sol.mu[1]  # the stage kept its own regularization


def test_continuation_stage_solves_its_model_and_seeds_the_next():
    from hydroilqr.solver.loop import solve as ilqr_solve

    task = Task.load("cartpole-wall", smoke=True, overrides="solver.max_iterations=2")
    staged = task.with_overrides({"continuation": [{"tip.hydroelastic_modulus": 1.0e5}]})
    stage = staged.stages()[0]
    ref0 = ilqr_solve(stage.problem(), staged.initial_guess(staged.steps), stage.config.solver)
    st = solve(staged).extra["continuation"]
    assert st[0]["final_cost"] == ref0.final_cost
    X = staged.dynamics.rollout(staged.x0, ref0.U)
    assert st[1]["start_cost"] == pytest.approx(staged.cost.total(X, ref0.U), rel=1e-12)


def test_a_continuation_reports_the_initial_cost_on_the_task_model():
    task = Task.load("cartpole-wall", smoke=True, overrides="solver.max_iterations=2")
    staged = task.with_overrides({"continuation": [{"tip.hydroelastic_modulus": 1.0e5}]})
    U0 = staged.initial_guess(staged.steps)
    own = staged.cost.total(staged.dynamics.rollout(staged.x0, U0), U0)
    sol = solve(staged)
    assert sol.stats()["initial_cost"] == sol.initial_cost == pytest.approx(own, rel=1e-12)


def test_a_dict_task_extends_a_file_relative_to_its_base_dir(tmp_path):
    from hydroilqr.problem.files import TASKS_DIR

    data = {"extends": "cartpole-wall.yaml", "name": "soft"}
    data["geometry"] = {"tip": {"hydroelastic_modulus": 1e5}}
    soft = Task.from_dict(data, base_dir=TASKS_DIR)
    assert soft.name == "soft" and soft.steps == Task.load("cartpole-wall").steps
    assert soft.config.geometry["tip"].hydroelastic_modulus == 1e5
    assert soft.config.geometry["tip"].dissipation == 0.0  # the rest of the parent's entry
    validate_task(soft)  # the parent's model path resolves
    # from another directory the parent's relative paths still resolve (to its own directory)
    elsewhere = Task.from_dict({**data, "extends": str(TASKS_DIR / "cartpole-wall.yaml")}, tmp_path)
    assert elsewhere.dynamics.nx == 4
    by_name = Task.from_dict({**data, "extends": "cartpole-wall"}, tmp_path)  # a built-in
    assert by_name.config.geometry["tip"].hydroelastic_modulus == 1e5 and by_name.steps == 200
    (tmp_path / "mine.yaml").write_text("extends: cartpole-wall\nname: mine\nhorizon: 0.5\n")
    assert Task.load(str(tmp_path / "mine.yaml")).steps == 50
    with pytest.raises(ConfigError, match="task: extends: no such file"):
        Task.from_dict({"extends": "nope.yaml"}, base_dir=tmp_path)
