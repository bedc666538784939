"""Mini Cheetah gait discovery (paper §IV-A): task setup and smoke-sized receding-horizon solves."""

import json
from pathlib import Path

import numpy as np
import pytest

from hydroilqr import Task, linearize
from hydroilqr.metrics import compute
from hydroilqr.output.results import checkpointer
from hydroilqr.problem.files import list_tasks
from hydroilqr.solver.api import solve
from hydroilqr.solver.receding import CHECKPOINT

TASKS = ["cheetah-trot-0.5", "cheetah-trot-1.0"]


class _Stop(Exception):
    pass


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory):
    """An uninterrupted smoke run (3 resolves of a 10-step window), checkpointed."""
    out = tmp_path_factory.mktemp("full")
    task = Task.load("cheetah-trot-1.0", smoke=True)
    sol = solve(task, checkpoint_dir=out, on_checkpoint=checkpointer(out))
    return task, sol, out


FEET = {"FL_foot_collision", "FR_foot_collision", "HL_foot_collision", "HR_foot_collision"}


SPLIT = Path(__file__).parents[2] / "examples" / "cheetah-split-ground.yaml"


def half_space_ground() -> Task:
    """examples/cheetah-split-ground.yaml: the feet touch a compliant half space with the box's
    pressure field near its top face (box 1 m thick: p = E d / 0.5 m; half space with slab
    0.5 m), the compliant body touches the box (a compliant half space cannot touch compliant
    geometry)."""
    return Task.from_yaml(SPLIT)


def _interrupt_after(resolves: int, task, directory) -> None:
    """Runs a receding-horizon task into ``directory`` and stops it after some resolves."""

    def stop(done, total, sol):
        if done == resolves:
            raise _Stop

    with pytest.raises(_Stop):
        solve(
            task, checkpoint_dir=directory, on_checkpoint=checkpointer(directory), on_resolve=stop
        )


def test_tasks_listed_and_paper_setup():
    assert set(TASKS) <= set(list_tasks())
    assert not any(name.startswith("_") for name in list_tasks())
    for name, v in zip(TASKS, (0.5, 1.0)):
        task = Task.load(name)
        cfg, dyn, cost = task.config, task.dynamics, task.cost
        assert (dyn.nq, dyn.nv, dyn.nu) == (19, 18, 12)
        assert dyn.dt == 0.005
        rh = cfg.receding_horizon
        assert (rh.window_steps, rh.shift_steps, rh.resolves) == (40, 4, 100)
        lay = dyn.layout
        dt = dyn.dt
        paper_q = {
            "orientation": 2.0,
            "position": 1.0,
            "joints": 0.0,
            "angular_velocity": 0.01,
            "velocity": 0.01,
            "joint_velocities": 0.01,
        }
        paper_qf = {
            "orientation": 10.0,
            "position": 5.0,
            "joints": 0.1,
            "angular_velocity": 1.0,
            "velocity": 1.0,
            "joint_velocities": 0.01,
        }
        for block, w in paper_q.items():
            np.testing.assert_allclose(cost.q[list(lay.block(block).tangent)], w * dt)
            np.testing.assert_allclose(cost.qf[list(lay.block(block).tangent)], paper_qf[block])
        np.testing.assert_allclose(cost.r, 0.01 * dt)
        # Nominal: level body moving forward at v, standing joints, velocity [v, 0, 0].
        x1 = cost.nominal(np.array([1.0]))[0]
        pos, vel = lay.block("position"), lay.block("velocity")
        np.testing.assert_allclose(x1[list(pos.coords)], [v, 0.0, 0.29166])
        np.testing.assert_allclose(x1[list(vel.coords)], [v, 0.0, 0.0])
        np.testing.assert_allclose(x1[list(lay.block("orientation").coords)], [1, 0, 0, 0])
        np.testing.assert_allclose(task.x0[list(lay.block("joints").coords)], [0, -0.8, 1.6] * 4)
        U = task.initial_guess(5)
        assert U.shape == (5, 12) and np.all(np.abs(U) <= dyn.effort_limits)


def test_standing_contacts():
    task = Task.load("cheetah-trot-0.5")
    surfaces = task.dynamics.contact_surfaces(task.x0)
    feet = {a for a, b, n in surfaces if "foot" in a and b == "ground" and n > 0}
    assert feet == FEET
    assert not any("body" in a for a, _, _ in surfaces)


def test_a_ground_of_two_geometries_each_touching_its_own():
    task = half_space_ground()
    dyn = task.dynamics
    inspector = dyn.scene_graph.model_inspector()
    names = {g: n for g, (n, _b) in dyn.geometry_names().items()}
    pairs = {frozenset((names[a], names[b])) for a, b in inspector.GetCollisionCandidates()}
    for foot in FEET:
        assert frozenset((foot, "ground_feet")) in pairs
        assert frozenset((foot, "ground")) not in pairs
    assert frozenset(("body_collision", "ground")) in pairs
    assert frozenset(("body_collision", "ground_feet")) not in pairs
    standing = {(a, b) for a, b, n in dyn.contact_surfaces(task.x0) if n > 0}
    assert standing == {(f, "ground_feet") for f in FEET}
    # Body dropped onto the ground: it touches the box.
    x = task.x0.copy()
    x[list(dyn.layout.block("position").coords)] = [0.0, 0.0, 0.02]
    touching = {frozenset((a, b)) for a, b, n in dyn.contact_surfaces(x) if n > 0}
    assert frozenset(("body_collision", "ground")) in touching
    # The standing state settles to the same height on both grounds (same pressure field).
    U = task.initial_guess(40)
    box = Task.load("cheetah-trot-1.0").dynamics
    z = dyn.layout.block("position").coords[2]
    assert abs(dyn.rollout(task.x0, U)[-1, z] - box.rollout(task.x0, U)[-1, z]) < 1e-5


@pytest.mark.parametrize("fd_forces", [False, True])
def test_standing_partials_autodiff_equal_central_differences(fd_forces):
    """Feet (rigid) on a compliant half space: AutoDiff is exact here, and central
    differences (over (x, u) or over generalized forces) agree with it to 1e-4 relative
    (issue 7's bar for exact modes)."""
    task = half_space_ground()
    task.config.solver.fd_forces = fd_forces
    dyn = task.dynamics
    assert task.config.solver.fd_forces is fd_forces and dyn.force_path() is not None
    rng = np.random.default_rng(3)
    u = task.initial_guess(1)[0]
    X = dyn.rollout(task.x0, np.tile(u, (6, 1)))
    x = X[-1] + 1e-4 * rng.standard_normal(dyn.nx)  # off the symmetric pose (a mesh kink)
    x[:4] /= np.linalg.norm(x[:4])
    A_ad, B_ad = linearize(dyn, x, u, method="autodiff")
    A_fd, B_fd = linearize(dyn, x, u, method="central", fd_forces=fd_forces)
    J_ad, J_fd = np.hstack([A_ad, B_ad]), np.hstack([A_fd, B_fd])
    assert len([s for s in dyn.contact_surfaces(x) if s[2] > 0]) == 4
    assert np.abs(J_fd - J_ad).max() / np.abs(J_ad).max() < 1e-4


def test_smoke_solve_shapes_and_cost_decrease(smoke_run, tmp_path):
    from hydroilqr.output import results

    task, sol, _ = smoke_run
    rh = task.config.receding_horizon
    n = rh.resolves * rh.shift_steps
    assert sol.X.shape == (n + 1, 37) and sol.U.shape == (n, 12)
    assert sol.K.shape == (n, 12, 37) and sol.t.shape == (n + 1,)
    assert np.all(np.isfinite(sol.X))
    res = sol.extra["resolves"]
    assert len(res) == rh.resolves and all(r["iterations"] >= 1 for r in res)
    # The first window's iterations never increase the cost, and the first one decreases it.
    first = sol.costs[: res[0]["iterations"] + 1]
    assert first[1] < first[0] and np.all(np.diff(first) <= 0)
    m = compute(task, sol)
    assert set(m["duty_factor"]) == {"FL", "FR", "HL", "HR"}
    for key in (
        "mean_forward_velocity_mps",
        "min_body_height_m",
        "diagonal_pair_overlap",
        "lateral_pair_overlap",
        "iterations_per_resolve",
    ):
        assert np.isfinite(m[key])
    assert set(m["pair_sync"]) == {"diagonal", "lateral", "front", "hind"}
    assert all(0.0 <= v <= 1.0 for v in m["pair_sync"].values())
    assert set(m["foot_slip_mps"]) == {"FL", "FR", "HL", "HR"}
    assert all(np.isfinite(v) and v >= 0 for v in m["foot_slip_mps"].values())
    assert np.isfinite(sol.extra["trajectory_cost"]) and sol.extra["trajectory_cost"] > 0
    assert m["target_velocity_mps"] == 1.0 and m["body_ground_contact_steps"] == 0
    assert m["max_foot_faces"] > 0
    summary = results.write_solve(task, sol, tmp_path, replay=False)
    assert (tmp_path / "velocity.png").exists() and (tmp_path / "gait.png").exists()
    saved = json.loads((tmp_path / "summary.json").read_text())
    assert saved["metrics"]["duty_factor"] == summary["metrics"]["duty_factor"]
    assert len(saved["extra"]["resolves"]) == rh.resolves


def test_resume_equals_uninterrupted(smoke_run, tmp_path):
    _, full, full_dir = smoke_run
    assert (full_dir / CHECKPOINT).exists()

    from hydroilqr.solver.receding import load_checkpoint

    _interrupt_after(2, Task.load("cheetah-trot-1.0", smoke=True), tmp_path)
    # A fresh process would rebuild the task; so does this.
    task = Task.load("cheetah-trot-1.0", smoke=True)
    assert load_checkpoint(task, tmp_path).done == 2
    seen = []  # only the missing resolve is computed
    resumed = solve(
        task,
        checkpoint_dir=tmp_path,
        on_checkpoint=checkpointer(tmp_path),
        on_resolve=lambda d, t, s: seen.append(d),
    )
    assert seen == [3]
    np.testing.assert_array_equal(resumed.X, full.X)
    np.testing.assert_array_equal(resumed.U, full.U)
    np.testing.assert_array_equal(resumed.K, full.K)
    np.testing.assert_array_equal(resumed.costs, full.costs)
    assert [r["iterations"] for r in resumed.extra["resolves"]] == [
        r["iterations"] for r in full.extra["resolves"]
    ]


def test_resume_refuses_another_runs_checkpoint(tmp_path, capsys):
    from hydroilqr.cli import main

    out = str(tmp_path / "run")
    one = ["--set", "receding_horizon.resolves=1", "--no-replay"]  # one window is enough here

    def err():
        return capsys.readouterr().err

    assert main(["solve", "cheetah-trot-1.0", "--smoke", "--out", out, *one]) == 0
    assert main(["solve", "cheetah-trot-0.5", "--smoke", "--resume", out, *one]) == 2
    assert "different run" in err()
    assert main(["solve", "cheetah-trot-1.0", "--smoke", "--resume", out + "x", *one]) == 2
    assert "runx: no checkpoint.npz there" in err()
    # A finished run may be solved again in place; an unfinished one needs --resume.
    assert main(["solve", "cheetah-trot-1.0", "--smoke", "--out", out, *one]) == 0
    (tmp_path / "run" / "summary.json").unlink()
    capsys.readouterr()
    assert main(["solve", "cheetah-trot-1.0", "--smoke", "--out", out, *one]) == 2
    assert f"pass --resume {out}" in err()
    assert main(["solve", "cheetah-trot-1.0", "--smoke", "--resume", out, *one]) == 0
    assert (tmp_path / "run" / "summary.json").exists()


def test_resume_refuses_a_checkpoint_whose_parts_disagree(smoke_run, tmp_path):
    import json
    import shutil

    from hydroilqr.problem.errors import ConfigError

    _, _, full_dir = smoke_run
    shutil.copy(full_dir / CHECKPOINT, tmp_path / CHECKPOINT)
    with np.load(tmp_path / CHECKPOINT) as d:
        arrays = dict(d)
    meta = json.loads(str(arrays["meta"]))
    meta["done"] = 1  # the arrays hold 3 resolves
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(tmp_path / CHECKPOINT, **arrays)
    with pytest.raises(ConfigError, match="disagree with each other"):
        solve(
            Task.load("cheetah-trot-1.0", smoke=True),
            checkpoint_dir=tmp_path,
            on_checkpoint=checkpointer(tmp_path),
        )


def test_pair_sync_names_the_gait():
    """pair_sync on synthetic contact patterns: a trot, a pace and a bound."""
    from hydroilqr.metrics.cheetah import pair_sync as sync

    phase = (np.arange(40) // 5) % 2 == 0  # 5 steps down, 5 up
    trot = np.stack([phase, ~phase, ~phase, phase], axis=1)  # FL+HR, FR+HL together
    pace = np.stack([phase, ~phase, phase, ~phase], axis=1)  # FL+HL, FR+HR together
    bound = np.stack([phase, phase, ~phase, ~phase], axis=1)  # fronts, hinds together
    assert sync(trot)["diagonal"] == 1.0 and sync(trot)["lateral"] == 0.0
    assert sync(pace)["lateral"] == 1.0 and sync(pace)["diagonal"] == 0.0
    assert sync(bound)["front"] == sync(bound)["hind"] == 1.0


def test_foot_slip_is_zero_standing_and_body_speed_when_dragged():
    """The slip of each foot's lowest point: 0 at rest, the body's speed when the whole robot
    translates rigidly."""
    from types import SimpleNamespace

    from hydroilqr.metrics.cheetah import foot_slip_speeds

    task = Task.load("cheetah-trot-1.0", smoke=True)
    x = task.x0.copy()
    lay = task.dynamics.layout
    still = foot_slip_speeds(task, SimpleNamespace(X=np.array([x])))
    np.testing.assert_allclose(still, 0.0, atol=1e-12)
    moving = x.copy()
    moving[list(lay.primitives["body.velocity"].coords)] = [0.6, 0.8, 0.0]  # 1 m/s level
    dragged = foot_slip_speeds(task, SimpleNamespace(X=np.array([moving])))
    np.testing.assert_allclose(dragged, 1.0, atol=1e-9)


def test_foot_load_standing_carries_the_weight():
    """Standing with the standing torques: the four feet carry the robot's weight between
    them, each about a quarter (front and hind legs are alike)."""
    from types import SimpleNamespace

    from hydroilqr.metrics.cheetah import foot_vertical_forces

    task = Task.load("cheetah-trot-1.0", smoke=True)
    dyn = task.dynamics
    U = np.tile(task.initial_guess(1)[0], (3, 1))
    X = dyn.rollout(task.x0, U)
    F = foot_vertical_forces(task, SimpleNamespace(X=X, U=U))
    mg = dyn.plant.CalcTotalMass(dyn.plant_context) * 9.81
    assert F.shape == (3, 4)
    np.testing.assert_allclose(F.sum(axis=1) / mg, 1.0, rtol=0.05)
    np.testing.assert_allclose(F / mg, 0.25, atol=0.05)


def test_checkpoint_of_other_settings_refused(tmp_path):
    from hydroilqr.problem.errors import ConfigError
    from hydroilqr.solver.receding import load_checkpoint

    def stop(done, total, sol):
        raise _Stop

    with pytest.raises(_Stop):
        solve(
            Task.load("cheetah-trot-1.0", smoke=True),
            checkpoint_dir=tmp_path,
            on_checkpoint=checkpointer(tmp_path),
            on_resolve=stop,
        )
    other = Task.load("cheetah-trot-1.0", ["cost.R=0.02"], smoke=True)
    with pytest.raises(ConfigError, match="different run"):
        load_checkpoint(other, tmp_path)


@pytest.mark.parametrize("tail", ["last", "guess"])
def test_windows_start_at_their_time_and_from_shifted_controls(monkeypatch, tail):
    from hydroilqr.solver import receding

    calls = []
    real = receding.solve

    def spy(problem, U0, *a, **k):
        sol = real(problem, U0, *a, **k)
        calls.append((problem.t0, np.array(U0), sol.U.copy(), problem.x0.copy()))
        return sol

    monkeypatch.setattr(receding, "solve", spy)
    task = Task.load(
        "cheetah-trot-1.0", overrides=[f"receding_horizon.warm_start_tail={tail}"], smoke=True
    )
    solve(task)
    rh, dt = task.config.receding_horizon, task.dynamics.dt
    assert [c[0] for c in calls] == pytest.approx(
        [r * rh.shift_steps * dt for r in range(rh.resolves)]
    )
    S, W = rh.shift_steps, rh.window_steps
    for r, ((_, _, U_prev, _), (_, U0, _, x0)) in enumerate(zip(calls, calls[1:]), start=1):
        np.testing.assert_array_equal(U0[:-S], U_prev[S:])
        if tail == "last":
            np.testing.assert_array_equal(U0[-S:], np.tile(U_prev[-1], (S, 1)))
        else:  # the task's initial guess for the window's last S time steps
            want = task.initial_guess(S, x0, start=r * S + W - S)
            np.testing.assert_array_equal(U0[-S:], want)


def test_resume_refuses_a_checkpoint_whose_model_file_changed(tmp_path):
    """The checkpoint also fingerprints the files the task reads: resuming after the model
    changed would stitch two models into one trajectory."""
    import shutil

    from hydroilqr.problem.errors import ConfigError
    from hydroilqr.problem.files import TASKS_DIR
    from hydroilqr.solver.receding import load_checkpoint

    model = tmp_path / "cheetah.sdf"
    shutil.copy(TASKS_DIR.parent / "models" / "mini_cheetah" / "mini_cheetah.sdf", model)
    task_file = tmp_path / "t.yaml"
    task_file.write_text(
        f"extends: {TASKS_DIR / 'cheetah-trot-1.0.yaml'}\nmodels:\n  - file: {model}\n"
    )

    _interrupt_after(1, Task.load(str(task_file), smoke=True), tmp_path)
    load_checkpoint(Task.load(str(task_file), smoke=True), tmp_path)  # unchanged: accepted
    model.write_text(model.read_text().replace("<mass>3.3</mass>", "<mass>4.5</mass>"))
    with pytest.raises(ConfigError, match="changed since its checkpoint"):
        load_checkpoint(Task.load(str(task_file), smoke=True), tmp_path)


def test_a_run_resumed_in_another_environment_says_so(tmp_path, monkeypatch):
    from hydroilqr.solver import receding

    _interrupt_after(1, Task.load("cheetah-trot-1.0", smoke=True), tmp_path)
    task = Task.load("cheetah-trot-1.0", smoke=True)
    st = receding.load_checkpoint(task, tmp_path)
    assert receding.environment_change(st) == ""  # same environment: nothing to say
    here = receding.numeric_environment()
    monkeypatch.setattr(
        receding, "numeric_environment", lambda: {**here, "blas_core": "Haswell-elsewhere"}
    )
    assert "blas_core" in receding.environment_change(st)
    sol = solve(
        Task.load("cheetah-trot-1.0", smoke=True),
        checkpoint_dir=tmp_path,
        on_checkpoint=checkpointer(tmp_path),
    )
    envs = sol.extra["environments"]
    assert [e["from_resolve"] for e in envs] == [0, 1]
    assert envs[1]["environment"]["blas_core"] == "Haswell-elsewhere"


def test_a_window_whose_warm_start_blows_up_starts_from_the_initial_guess(monkeypatch):
    """If the shifted previous window cannot be rolled out from the kept state (its held last
    control blows the simulation up), the window starts cold from the task's initial guess
    instead of ending the run; the resolve records it."""
    from hydroilqr.model.plant import SimulationError

    task = Task.load("cheetah-trot-1.0", smoke=True)
    dyn = task.dynamics
    rollout = dyn.rollout
    calls = []

    def failing_once(x0, U):
        calls.append(1)
        if len(calls) == 2:  # the second window's warm start
            raise SimulationError("step 9: the simulation diverged")
        return rollout(x0, U)

    monkeypatch.setattr(dyn, "rollout", failing_once)
    sol = solve(task)
    res = sol.extra["resolves"]
    assert [r.get("cold_start", False) for r in res] == [False, True, False]
    assert sol.X.shape == (task.config.receding_horizon.resolves * 4 + 1, dyn.nx)
    assert np.isfinite(sol.X).all()


def test_a_window_whose_warm_start_and_guess_both_blow_up_names_both(monkeypatch):
    from hydroilqr.model.plant import SimulationError

    task = Task.load("cheetah-trot-1.0", smoke=True)
    dyn = task.dynamics

    def failing(x0, U):
        raise SimulationError("step 3: the simulation diverged")

    monkeypatch.setattr(dyn, "rollout", failing)
    with pytest.raises(SimulationError, match="resolve 0: initial rollout failed from the shifted"):
        solve(task)


def test_new_keys_at_their_defaults_keep_old_checkpoints_fingerprints():
    """Checkpoints written before receding_horizon.warm_start_tail and rescue_factor, scene
    no_contact_with and solver.fd_forces existed still resume: at their defaults those keys do
    not enter the fingerprint."""
    import dataclasses
    import hashlib
    import json

    from hydroilqr.solver.receding import fingerprint

    def before(cfg):  # the fingerprint as computed before the two keys existed
        d = dataclasses.asdict(cfg)
        d.pop("base_dir", None)
        for key in ("threads", "autodiff_workers", "line_search_workers"):
            d.get("solver", {}).pop(key, None)
        d.pop("mpc", None)
        del d["receding_horizon"]["warm_start_tail"]
        del d["receding_horizon"]["rescue_factor"], d["receding_horizon"]["rescue_iterations"]
        del d["solver"]["fd_forces"]
        for o in d["scene"]:
            del o["no_contact_with"]
        for key in ("goal", "smoke_run", "actuators"):  # keys added since
            del d[key]
        for m in d["models"]:
            del m["name"]
        text = json.dumps(d, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    task = Task.load("cheetah-trot-1.0", ["receding_horizon.rescue_factor=0"], smoke=True)
    assert fingerprint(task.config, legacy=True) == before(task.config)
    rescued = Task.load("cheetah-trot-1.0", smoke=True)  # (the built-in rescues windows)
    assert fingerprint(rescued.config) != fingerprint(task.config)
    other = Task.load(
        "cheetah-trot-1.0", overrides=["receding_horizon.warm_start_tail=guess"], smoke=True
    )
    assert fingerprint(other.config) != fingerprint(task.config)
    forces = Task.load("cheetah-trot-1.0", overrides=["solver.fd_forces=true"], smoke=True)
    assert fingerprint(forces.config) != fingerprint(task.config)


def test_solve_says_which_windows_started_cold(monkeypatch, tmp_path, capsys):
    from hydroilqr import cli
    from hydroilqr.solver import receding

    real, calls = receding._warm_start, []

    def second_cold(task, guess, x0, k0):
        calls.append(k0)
        U, X, _ = real(task, guess, x0, k0)
        return U, X, len(calls) == 2

    monkeypatch.setattr(receding, "_warm_start", second_cold)
    two = ["--set", "receding_horizon.resolves=2", "--no-replay"]  # (the second starts cold)
    rc = cli.main(["solve", "cheetah-trot-1.0", "--smoke", "--out", str(tmp_path), *two])
    assert rc == 0
    assert (
        "note: 1 window(s) started from the initial guess (resolves 1)" in capsys.readouterr().out
    )


def test_solve_says_how_many_windows_were_rescued(monkeypatch, tmp_path, capsys):
    from hydroilqr import cli
    from hydroilqr.solver import receding

    def second_rescued(problem, sol, st, rh, solver, callbacks):
        if st.done == 1:
            sol.extra["rescue"] = {"cost_before": 2, "cost_after": 1, "iterations": 2, "kept": 1}
        return sol

    monkeypatch.setattr(receding, "_rescued", second_rescued)
    two = ["--set", "receding_horizon.resolves=2", "--no-replay"]  # (the second is rescued)
    rc = cli.main(["solve", "cheetah-trot-1.0", "--smoke", "--out", str(tmp_path), *two])
    assert rc == 0
    out = capsys.readouterr().out
    assert "note: 1 window(s) ended above 2x the recent windows' median cost" in out
    summary = __import__("json").loads((tmp_path / "summary.json").read_text())
    assert [bool(r.get("rescue")) for r in summary["extra"]["resolves"]] == [False, True]


def _first_window(task):
    """Window 0 of a smoke cheetah solved with its own settings: (problem, solution, solver)."""
    from hydroilqr.model.task import Problem
    from hydroilqr.solver import receding

    rh, solver = task.config.receding_horizon, task.config.solver
    problem = Problem(task.dynamics, task.cost, task.x0, 0.0)
    guess = task.initial_guess(rh.window_steps)
    sol = receding.solve(problem, guess, solver, None, rh.max_iterations, final_gains=True)
    return problem, sol, solver


def test_a_window_whose_cost_jumps_is_solved_on_and_the_better_kept():
    """rescue_factor: a window whose cost is above the factor times the median of the previous
    windows' gets rescue_iterations more iterations from where it stopped; the result is that
    continuation, with the window's own iterations first, and it records the rescue."""
    import dataclasses

    from hydroilqr.model.plant import SimulationError
    from hydroilqr.solver import receding

    task = Task.load("cheetah-trot-1.0", smoke=True)
    problem, sol, solver = _first_window(task)
    rh = dataclasses.replace(task.config.receding_horizon, rescue_factor=2.0, rescue_iterations=2)
    st = receding.Checkpoint.start(task.x0, sol.U, task.dynamics.nx, task.dynamics.nu)
    st.resolves = [{"cost": sol.final_cost}]  # no jump: kept as it is
    assert receding._rescued(problem, sol, st, rh, solver, None) is sol
    assert "rescue" not in sol.extra
    st.resolves = [{"cost": sol.final_cost / 3}, {"cost": sol.final_cost / 2.5}]
    out = receding._rescued(problem, sol, st, rh, solver, None)
    on = receding.solve(problem, sol.U, solver, None, 2, final_gains=True, X0=sol.X)
    rec = out.extra["rescue"]
    assert rec["cost_before"] == sol.final_cost and rec["cost_after"] == on.final_cost
    assert rec["kept"] == (on.final_cost < sol.final_cost)
    if rec["kept"]:
        np.testing.assert_array_equal(out.X, on.X)
        np.testing.assert_array_equal(out.costs, np.concatenate([sol.costs, on.costs[1:]]))
        assert out.iterations == sol.iterations + on.iterations
        assert len(out.iteration_seconds) == out.iterations
    else:
        np.testing.assert_array_equal(out.X, sol.X)
    off = dataclasses.replace(rh, rescue_factor=0.0)
    assert receding._rescued(problem, sol, st, off, solver, None) is sol

    def blows_up(*a, **k):
        raise SimulationError("step 3: the simulation diverged")

    real = receding.solve
    receding.solve = blows_up
    try:  # a rescue that fails leaves the window as solved; it never ends the run
        assert receding._rescued(problem, sol, st, rh, solver, None) is sol
    finally:
        receding.solve = real


def test_a_rescue_is_recorded_in_the_windows_entry():
    from hydroilqr.solver import receding

    task = Task.load("cheetah-trot-1.0", smoke=True)
    _, sol, _ = _first_window(task)
    st = receding.Checkpoint.start(task.x0, sol.U, task.dynamics.nx, task.dynamics.nu)
    rec = {"cost_before": 2.0, "cost_after": 1.0, "iterations": 2, "kept": True}
    sol.extra["rescue"] = rec
    receding._keep(task, st, sol, False, 1.0, 0.0)
    assert st.resolves[0]["rescue"] == rec
