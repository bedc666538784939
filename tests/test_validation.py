"""Every bad key gives a one-line error naming it, before any solve starts (issue 9).

Each case writes a task file next to nothing but itself (the model is Drake's acrobot or
pendulum, shipped in the drake wheel), runs ``hydroilqr solve`` on it and checks: non-zero exit,
exactly one line on stderr, no traceback, the offending key in the message, nothing printed on
stdout (so the solve never started). All cases run in-process through ``cli.main``; a subset
also runs as real subprocesses of the installed ``hydroilqr`` script.
"""

from __future__ import annotations

import copy
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from hydroilqr import cli
from hydroilqr.problem.config import ConfigError

ACROBOT = "package://drake/examples/acrobot/Acrobot.urdf"
PENDULUM = "package://drake/examples/pendulum/Pendulum.urdf"
HYDROILQR = Path(sys.executable).parent / "hydroilqr"

BASE = {
    "name": "val",
    "models": [{"file": ACROBOT}],
    "plant": {"time_step": 0.02},
    "num_steps": 5,
    "blocks": {"angles": ["shoulder", "elbow"]},
    "initial_state": {"angles": [0.1, 0.0]},
    "cost": {
        "Q": {"angles": 1.0},
        "R": 0.01,
        "Qf": {"angles": 10.0},
        "nominal": {"angles": [3.14, 0.0]},
    },
    "solver": {"max_iterations": 1},
}


def edit(**changes):
    """BASE with dotted-key changes ('cost.Q.angles': -1); value None deletes the key."""
    data = copy.deepcopy(BASE)
    for dotted, value in changes.items():
        *path, last = dotted.split("__")
        node = data
        for p in path:
            node = node.setdefault(p, {})
        if value is None:
            node.pop(last, None)
        else:
            node[last] = value
    return data


# (case id, task dict or raw YAML text, text the one-line message must contain)
CASES = [
    ("unknown-top-level-key", edit(horizn=2.0), "horizn: unknown key"),
    ("unknown-block-in-Q", edit(cost__Q={"angels": 1.0}), "cost.Q.angels"),
    ("wrong-length-weights", edit(cost__Q={"angles": [1, 2, 3]}), "cost.Q.angles"),
    ("negative-weight", edit(cost__Qf={"angles": -1.0}), "cost.Qf.angles"),
    ("nan-weight", edit(cost__Q={"angles": float("nan")}), "cost.Q.angles"),
    ("nan-weight-in-list", edit(cost__Q={"angles": [1.0, float("nan")]}), "cost.Q.angles"),
    ("unknown-actuator-in-R", edit(cost__R={"shoulder": 1.0}), "cost.R.shoulder"),
    ("wrong-length-R", edit(cost__R=[1.0, 2.0]), "cost.R"),
    (
        "negative-modulus",
        edit(geometry={"lower_link_collision": {"hydroelastic_modulus": -1e6}}),
        "geometry.lower_link_collision.hydroelastic_modulus",
    ),
    ("unknown-geometry", edit(geometry={"gripper_pad": {"friction": 0.5}}), "geometry.gripper_pad"),
    (
        "unknown-weld-frame",
        edit(
            models=[{"file": PENDULUM, "weld": {"parent": "world", "child": "no_such_link"}}],
            blocks={},
            initial_state={},
            cost={"R": 0.1},
        ),
        "models[0].weld.child",
    ),
    ("missing-model-file", edit(models=[{"file": "robots/missing.urdf"}]), "models[0].file"),
    (
        "missing-package-file",
        edit(models=[{"file": "package://drake/examples/none.urdf"}]),
        "models[0].file",
    ),
    ("malformed-yaml", "models:\n  - file: [unclosed\ncost: {Q: 1\n", "line"),
    (
        "compliant-halfspace-pair",
        edit(
            models=[{"file": PENDULUM}],
            blocks={},
            initial_state={},
            cost={"R": 0.1},
            scene=[
                {
                    "name": "soft_floor",
                    "shape": "halfspace",
                    "xyz": [0, 0, 0.49],
                    "compliance": "compliant",
                    "hydroelastic_modulus": 1e6,
                }
            ],
            geometry={"arm_com": {"hydroelastic_modulus": 1e6, "resolution_hint": 0.02}},
        ),
        "scene[0] (soft_floor)",
    ),
    (
        "bad-warm-start-tail",
        edit(receding_horizon={"warm_start_tail": "hold"}),
        "receding_horizon.warm_start_tail",
    ),
    (
        "unknown-no-contact-with",
        edit(scene=[{"name": "wall", "shape": "box", "no_contact_with": ["gripper"]}]),
        "scene[0].no_contact_with: no collision geometry or body named 'gripper'",
    ),
    ("unknown-initial-state-block", edit(initial_state={"knee": 0.3}), "initial_state.knee"),
    (
        "wrong-length-initial-state",
        edit(initial_state={"angles": [1, 2, 3]}),
        "initial_state.angles",
    ),
    ("unknown-group-member", edit(blocks={"angles": ["shoulder", "wrist"]}), "blocks.angles"),
    (
        "bad-contact-approximation",
        edit(plant={"contact_approximation": "magic"}),
        "plant.contact_approximation",
    ),
    ("negative-time-step", edit(plant={"time_step": -0.01}), "plant.time_step"),
    ("string-for-number", edit(horizon="long"), "horizon"),
    ("bad-initial-guess", edit(initial_guess="warm.npz"), "initial_guess"),
    ("unknown-metric", edit(metrics=["default", "speed"]), "metrics"),
    ("unknown-solver-key", edit(solver={"max_iter": 3}), "solver.max_iter"),
    # Vectors of the wrong length are named, not passed on to Drake.
    ("short-gravity", edit(plant={"gravity": [0, -9.81]}), "plant.gravity: expected 3 numbers"),
    (
        "short-weld-xyz",
        edit(
            models=[{"file": PENDULUM, "weld": {"child": "base", "xyz": [0, 0]}}],
            blocks={},
            initial_state={},
            cost={"R": 0.1},
        ),
        "models[0].weld.xyz: expected 3 numbers",
    ),
    (
        "short-scene-xyz",
        edit(scene=[{"name": "floor", "shape": "box", "size": [1, 1, 1], "xyz": [0, 0]}]),
        "scene[0].xyz: expected 3 numbers",
    ),
    (
        "bad-scene-color",
        edit(scene=[{"name": "floor", "shape": "box", "color": [0.5, 0.5]}]),
        "scene[0].color",
    ),
    (
        "sphere-with-size",
        edit(scene=[{"name": "ball", "shape": "sphere", "size": [0.2, 0.2, 0.2]}]),
        "scene[0].size: a sphere uses radius",
    ),
    (
        "rigid-cylinder-without-hint",
        edit(geometry={"lower_link_collision": {"compliance": "rigid"}}),
        "geometry.lower_link_collision: resolution_hint is required",
    ),
    # A one-element list for a two-coordinate block is a mistake, not a broadcast.
    ("one-element-list", edit(initial_state={"angles": [0.05]}), "initial_state.angles"),
    ("one-element-nominal", edit(cost__nominal={"angles": [3.14]}), "cost.nominal.angles"),
    ("line-search-factor", edit(solver={"line_search_factor": 1.5}), "solver.line_search_factor"),
    ("negative-regularization", edit(solver={"regularization_init": -1}), "regularization_init"),
    ("negative-num-steps", edit(num_steps=-3), "num_steps"),
    ("horizon-off-grid", edit(num_steps=None, horizon=0.05), "not a whole number of time steps"),
    ("unknown-shape", edit(scene=[{"name": "f", "shape": "cone"}]), "scene[0].shape: expected"),
    ("name-as-path", edit(name="../../escape"), "name: '../../escape'"),
    (
        "duplicate-scene-names",
        edit(scene=[{"name": "f", "shape": "box"}, {"name": "f", "shape": "box"}]),
        "two objects are named 'f'",
    ),
    ("horizon-and-num-steps", edit(horizon=1.0), "give horizon or num_steps, not both"),
    ("duplicate-key", "models: []\nnum_steps: 5\nnum_steps: 6\n", "'num_steps' given twice"),
    ("extends-itself", "extends: task.yaml\nnum_steps: 5\n", "loops back on itself"),
    ("extends-a-list", "extends: [a.yaml, b.yaml]\n", "extends: expected one file name"),
    (
        "unknown-contact-model",
        edit(plant={"time_step": 0.02, "contact_model": "strict"}),
        "plant.contact_model: expected one of",
    ),
    ("missing-package-dir", edit(package_map={"mine": "no_such_dir"}), "package_map.mine"),
    ("mpc-derivatives", edit(mpc={"derivatives": "foo"}), "mpc.derivatives: expected one of"),
    ("mpc-derivative-interval", edit(mpc={"derivative_interval": -1}), "mpc.derivative_interval"),
    ("nominal-time", edit(cost__nominal_time="end"), "cost.nominal_time"),
    (
        "shift-longer-than-window",
        edit(receding_horizon={"window_steps": 2, "shift_steps": 4, "resolves": 1}),
        "receding_horizon.shift_steps",
    ),
]


def write_case(tmp_path: Path, spec) -> Path:
    path = tmp_path / "task.yaml"
    path.write_text(spec if isinstance(spec, str) else yaml.safe_dump(spec))
    return path


def assert_one_line(rc: int, out: str, err: str, needle: str) -> None:
    assert rc != 0
    assert "Traceback" not in err and "Traceback" not in out
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("hydroilqr: error: "), lines[0]
    assert needle in lines[0], lines[0]
    assert out.strip() == "", f"the solve started: {out}"


@pytest.mark.parametrize("case,spec,needle", CASES, ids=[c[0] for c in CASES])
def test_bad_key_in_process(tmp_path, capsys, case, spec, needle):
    path = write_case(tmp_path, spec)
    rc = cli.main(
        ["solve", "--task-file", str(path), "--out", str(tmp_path / "out"), "--no-replay"]
    )
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, needle)
    assert not (tmp_path / "out" / "solution.npz").exists()


def test_unknown_task_name(capsys):
    rc = cli.main(["solve", "no-such-task", "--out", "/nonexistent/never"])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "unknown task 'no-such-task'")
    assert "cartpole-wall" in cap.err  # lists the built-in tasks


def test_bad_override_names_key(tmp_path, capsys):
    path = write_case(tmp_path, BASE)
    rc = cli.main(
        [
            "solve",
            "--task-file",
            str(path),
            "--set",
            "solver.derivatives=magic",
            "--out",
            str(tmp_path / "o"),
        ]
    )
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "solver.derivatives")


SUBPROCESS_CASES = [
    "unknown-top-level-key",
    "nan-weight",
    "malformed-yaml",
    "compliant-halfspace-pair",
]


def test_bad_keys_as_subprocesses(tmp_path):
    """The real script: exit code, exactly one stderr line, no traceback (2 at a time)."""
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    env.pop("HYDROILQR_DEBUG", None)
    specs = {c[0]: (c[1], c[2]) for c in CASES}
    jobs = []
    for name in SUBPROCESS_CASES + ["unknown-task"]:
        d = tmp_path / name
        d.mkdir()
        if name == "unknown-task":
            argv = ["solve", "no-such-task"]
            needle = "unknown task"
        else:
            spec, needle = specs[name]
            argv = ["solve", "--task-file", str(write_case(d, spec))]
        jobs.append((name, needle, [str(HYDROILQR), *argv, "--out", str(d / "out")], d))
    running = []
    results = []
    while jobs or running:
        while jobs and len(running) < 2:
            name, needle, cmd, d = jobs.pop(0)
            p = subprocess.Popen(
                cmd, cwd=d, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
            )
            running.append((name, needle, p))
        name, needle, p = running.pop(0)
        out, err = p.communicate(timeout=120)
        results.append((name, needle, p.returncode, out, err))
    for name, needle, rc, out, err in results:
        assert rc == 2, (name, rc, err)
        assert_one_line(rc, out, err, needle)


@pytest.mark.parametrize(
    "override,needle",
    [
        # A typo after a geometry shorthand names the contact properties, not top-level keys.
        ("lower_link_collision.hydroelastic_modulu=1e6", "did you mean 'hydroelastic_modulus'"),
        ("solver.max_iter=3", "did you mean 'max_iterations'"),
    ],
)
def test_override_typo_suggests(tmp_path, capsys, override, needle):
    path = write_case(tmp_path, BASE)
    rc = cli.main(["solve", "--task-file", str(path), "--set", override, "--no-replay"])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, needle)


def test_smoke_typo_is_named_as_smoke(tmp_path, capsys):
    path = write_case(tmp_path, edit(smoke={"solver.max_iteratons": 1}))
    rc = cli.main(["solve", "--task-file", str(path), "--smoke", "--no-replay"])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "smoke: solver.max_iteratons")


def test_extends_across_directories_keeps_base_paths(tmp_path):
    """A base in another directory keeps resolving its own relative model and guess paths."""
    from hydroilqr.problem.config import load_task

    base_dir, child_dir = tmp_path / "shared", tmp_path / "mine"
    base_dir.mkdir()
    child_dir.mkdir()
    (base_dir / "robot.urdf").write_text(
        '<robot name="r"><link name="a"><inertial><mass value="1"/>'
        '<inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial></link></robot>'
    )
    (base_dir / "guess.csv").write_text("0\n")
    base = {"models": [{"file": "robot.urdf"}], "initial_guess": "guess.csv", "num_steps": 3}
    (base_dir / "base.yaml").write_text(yaml.safe_dump(base))
    (child_dir / "task.yaml").write_text("extends: ../shared/base.yaml\nname: child\n")
    cfg = load_task(str(child_dir / "task.yaml"))
    assert cfg.resolve_path(cfg.models[0].file) == base_dir / "robot.urdf"
    assert cfg.resolve_path(cfg.initial_guess) == base_dir / "guess.csv"


def test_scalar_weight_still_applies_to_a_whole_block():
    from hydroilqr.problem.task import Task

    path_spec = edit(initial_state={"angles": 0.05})
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        task = Task.load(str(write_case(Path(d), path_spec)))
        np.testing.assert_allclose(task.x0[:2], [0.05, 0.05])


def test_short_initial_guess_file_is_an_error(tmp_path, capsys):
    (tmp_path / "U.csv").write_text("0.1\n0.2\n")  # 2 rows, the task has 5 steps
    path = write_case(tmp_path, edit(initial_guess="U.csv"))
    rc = cli.main(["solve", "--task-file", str(path), "--no-replay", "--out", str(tmp_path / "o")])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "has 2 rows; the task needs 5")
    (tmp_path / "U.csv").write_text("0.1\n")  # one row: a constant control
    from hydroilqr.problem.task import Task

    np.testing.assert_allclose(Task.load(str(path)).initial_guess(5), np.full((5, 1), 0.1))


def test_command_line_guess_path_is_relative_to_the_working_directory(tmp_path, monkeypatch):
    from hydroilqr.problem.task import Task

    task_dir, work = tmp_path / "tasks", tmp_path / "work"
    task_dir.mkdir()
    work.mkdir()
    path = write_case(task_dir, BASE)
    (work / "U.csv").write_text("0.3\n")
    monkeypatch.chdir(work)
    task = Task.load(str(path), overrides=["initial_guess=U.csv"])
    np.testing.assert_allclose(task.initial_guess(5), np.full((5, 1), 0.3))


def test_check_validates_the_smoke_section(tmp_path, capsys):
    path = write_case(tmp_path, edit(smoke={"solver.max_iterations": -1}))
    rc = cli.main(["check", str(path)])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "solver.max_iterations")


def test_set_reaches_blocks_with_dots_in_their_names(tmp_path):
    """Velocity blocks (`shoulder.v`) and floating-body blocks (`ball.position`) by --set."""
    from hydroilqr.problem.task import Task

    path = write_case(tmp_path, BASE)
    task = Task.load(
        str(path), ["cost.Q.shoulder.v=0.5", "initial_state.elbow=0.2", "cost.Qf.elbow.v=2"]
    )
    assert task.config.cost.Q == {"angles": 1.0, "shoulder.v": 0.5}  # merged, not replaced
    assert task.config.cost.Qf["elbow.v"] == 2
    v = task.dynamics.layout.block("shoulder.v").tangent[0]
    assert task.cost.q[v] == 0.5


def test_horizon_on_the_command_line_wins_over_num_steps(tmp_path):
    from hydroilqr.problem.task import Task

    path = write_case(tmp_path, BASE)  # num_steps: 5
    assert Task.load(str(path), ["horizon=0.2"]).config.steps == 10


def test_geometry_keys_by_body_collision_name_or_both(tmp_path, capsys):
    """A collision name matches every geometry of that name, a body name all of the body's;
    a body name that is also another body's collision name is ambiguous; BODY/NAME picks one."""
    from hydroilqr.model.plant import geometry_hits

    geoms = {1: ("Sphere", "arm"), 2: ("Sphere", "base"), 3: ("arm", "base"), 4: ("Box", "arm")}
    assert geometry_hits("Sphere", geoms) == [1, 2]  # every geometry of that name
    assert geometry_hits("base/Sphere", geoms) == [2]
    from hydroilqr.problem.config import ConfigError

    with pytest.raises(ConfigError, match="ambiguous"):
        geometry_hits("arm", geoms)  # body arm, and a collision named arm on base
    assert geometry_hits("Box", geoms) == [4]


def test_out_that_is_a_file_or_another_tasks_directory(tmp_path, capsys):
    path = write_case(tmp_path, BASE)
    (tmp_path / "afile").write_text("x")
    rc = cli.main(["solve", str(path), "--out", str(tmp_path / "afile"), "--no-replay"])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "exists and is not a directory")
    other = tmp_path / "other"
    other.mkdir()
    (other / "mpc.json").write_text('{"task": "cartpole-wall"}')
    rc = cli.main(["mpc", str(path), "--duration", "0.1", "--out", str(other), "--no-replay"])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "holds the results of task 'cartpole-wall'")


def test_bench_block_must_be_positive(capsys):
    rc = cli.main(["bench", "cartpole-wall", "--smoke", "--block", "0", "--out", "/nonexistent"])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "--block")


def test_smoke_section_cannot_change_itself(tmp_path, capsys):
    path = write_case(tmp_path, edit(smoke={"smoke.num_steps": 3}))
    rc = cli.main(["check", str(path)])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "the smoke section cannot change itself")


def test_smoke_values_are_validated_as_smoke(tmp_path, capsys):
    path = write_case(tmp_path, edit(smoke={"num_steps": -1}))
    rc = cli.main(["solve", str(path), "--smoke", "--no-replay", "--out", str(tmp_path / "o")])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "smoke: num_steps")


def test_empty_guess_file_is_one_line(tmp_path, capsys):
    (tmp_path / "empty.csv").write_text("")
    path = write_case(tmp_path, edit(initial_guess="empty.csv"))
    rc = cli.main(["solve", str(path), "--out", str(tmp_path / "o"), "--no-replay"])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "empty.csv is empty")


@pytest.mark.parametrize(
    "option",
    [
        ["--duration", "nan"],
        ["--rate", "inf"],
        ["--threads", "-2"],
        ["--push", "nan:lower_link:1,0,0"],
        ["--push-duration", "nan", "--push", "0.01:lower_link:1,0,0"],
        ["--push-duration", "0.2"],
    ],
)
def test_mpc_rejects_non_finite_or_negative_options(tmp_path, capsys, option):
    path = write_case(tmp_path, BASE)
    rc = cli.main(["mpc", str(path), "--out", str(tmp_path / "o"), "--no-replay", *option])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, option[0].lstrip("-").split("-")[0])


def test_task_file_that_is_not_utf8(tmp_path, capsys):
    path = tmp_path / "task.yaml"
    path.write_bytes(b"name: x\nnum_steps: \xff\xfe\n")
    rc = cli.main(["check", str(path)])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "not UTF-8 text")


def test_smoke_does_not_claim_the_task_own_mistakes(tmp_path, capsys):
    path = write_case(tmp_path, edit(models=[{"file": "robots/missing.urdf"}]))
    rc = cli.main(["solve", "--task-file", str(path), "--smoke", "--no-replay"])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "models[0].file")
    assert "smoke:" not in cap.err


def test_overflowing_cost_is_an_error_not_a_finish(tmp_path, capsys):
    path = write_case(
        tmp_path, edit(cost__Qf={"angles": 1e308}, initial_state={"angles": [2.0, 1.0]})
    )
    rc = cli.main(["solve", "--task-file", str(path), "--out", str(tmp_path / "o"), "--no-replay"])
    cap = capsys.readouterr()
    assert rc != 0 and "Traceback" not in cap.err and "RuntimeWarning" not in cap.err
    lines = [ln for ln in cap.err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "cost of the initial guess is inf" in lines[0], cap.err
    assert not (tmp_path / "o" / "solution.npz").exists()


def test_run_files_that_disagree_are_refused(tmp_path):
    from hydroilqr.problem.config import ConfigError
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


def test_output_dir_with_unreadable_results_is_left_alone(tmp_path):
    from hydroilqr.output.report import output_dir
    from hydroilqr.problem.config import ConfigError

    (tmp_path / "summary.json").write_text("{torn")
    with pytest.raises(ConfigError, match="summary.json is unreadable"):
        output_dir(tmp_path, "cartpole-wall")


def test_a_run_directory_named_like_the_task_is_not_a_task_file(tmp_path, monkeypatch):
    from hydroilqr.problem.config import load_task

    monkeypatch.chdir(tmp_path)
    (tmp_path / "cartpole-wall").mkdir()  # e.g. `solve cartpole-wall --out cartpole-wall`
    assert load_task("cartpole-wall").name == "cartpole-wall"
    (tmp_path / "mine.yaml").mkdir()
    with pytest.raises(ConfigError, match="a directory, not a task YAML file"):
        load_task("mine.yaml")


def test_a_later_layer_horizon_wins_over_an_earlier_num_steps(tmp_path):
    from hydroilqr.problem.config import load_task

    path = write_case(tmp_path, BASE)  # num_steps: 5 at dt 0.02
    extra = tmp_path / "extra.yaml"
    extra.write_text("horizon: 0.2\n")
    assert load_task(str(path), config_file=str(extra)).steps == 10
    smoke = write_case(tmp_path, edit(smoke={"horizon": 0.06}))
    assert load_task(str(smoke), smoke=True).steps == 3
    (tmp_path / "child.yaml").write_text(f"extends: {path.name}\nhorizon: 0.4\n")
    assert load_task(str(tmp_path / "child.yaml")).steps == 20


def test_continuation_stages_keep_the_grid_and_read_paths_from_the_task_file(tmp_path):
    from hydroilqr.problem.task import Task

    path = write_case(tmp_path, edit(continuation=[{"plant": {"time_step": 0.04}}]))
    with pytest.raises(ConfigError, match="time grid"):
        Task.load(str(path)).stages()
    path = write_case(tmp_path, edit(continuation=[{"initial_guess": "guess.csv"}]))
    with pytest.raises(ConfigError, match="initial_guess cannot change"):
        Task.load(str(path))
    (tmp_path / "u.csv").write_text("0.1\n")
    path = write_case(tmp_path, edit(continuation=[{"cost.R": 0.02}], initial_guess="u.csv"))
    stage = Task.load(str(path)).stages()[0]
    assert stage.config.resolve_path(stage.config.initial_guess) == tmp_path / "u.csv"


def test_a_weld_names_a_frame_of_its_own_model(tmp_path, capsys):
    spec = edit(
        models=[
            {"file": PENDULUM},
            {"file": ACROBOT, "weld": {"parent": "world", "child": "arm"}},  # the pendulum's
        ],
        blocks={},
        initial_state={},
        cost={"R": 0.1},
    )
    path = write_case(tmp_path, spec)
    rc = cli.main(["check", str(path)])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "models[1].weld.child: unknown frame 'arm'")


def test_check_names_a_deep_initial_overlap_even_when_the_rollout_survives(capsys):
    deep = "initial_state.ball_position=[0.4, 0, 0.06]"  # 4 cm into the floor
    rc = cli.main(["check", "kinova-forward", "--set", deep])
    out = capsys.readouterr().out
    assert rc == 0 and "ball_collision (ball) and ground (world) overlap by 40 mm" in out
    assert cli.main(["check", "kinova-forward"]) == 0  # resting 1.6 mm deep: no warning
    assert "overlap by" not in capsys.readouterr().out
