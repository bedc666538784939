"""The metric registry: families, plots and sweep columns per metric, parameter validation
before any solve, the generic object metric, the contact timeline, the figure helper."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from hydroilqr import metrics
from hydroilqr.metrics import validate_task
from hydroilqr.model.task import Task
from hydroilqr.problem.errors import ConfigError


def test_registry_declares_compute_plots_and_sweep_columns():
    for name in ("default", "contacts", "cartpole_wall", "object", "kinova", "cheetah"):
        m = metrics.METRICS[name]
        assert m.name == name and callable(m.compute)
    assert metrics.METRICS["default"].file_names() == ("contacts.png",)
    assert metrics.METRICS["cheetah"].file_names() == ("velocity.png", "gait.png")
    assert metrics.METRICS["object"].file_names({"object": "box"}) == ("box.png",)
    assert metrics.METRICS["kinova"].file_names({"ball": "ball"}) == ("ball.png",)
    assert {"contacts.png", "velocity.png", "gait.png"} <= metrics.plot_files()
    lead, extra = metrics.sweep_columns(["default", "cartpole_wall"])
    assert lead == ["max_overlap_m", "tunnelled"] and "wall_contact_steps" in extra
    assert metrics.sweep_columns(["default", "cheetah"]) == ([], [])
    with pytest.raises(ConfigError, match="unknown metric 'nosuch'"):
        metrics.get("nosuch")


def test_sweep_columns_come_from_the_task_metrics():
    from hydroilqr.studies.sweep import POINT_COLUMNS, columns

    assert "max_overlap_m" not in POINT_COLUMNS and "tunnelled" not in POINT_COLUMNS
    rows = [{"id": "a", "param:k": 1.0, "final_cost": 1.0, "wall_contact_steps": 2, "worker": "w"}]
    cols = columns(["k"], rows, metrics.sweep_columns(["default", "cartpole_wall"]))
    assert cols[:4] == ["k", "final_cost", "max_overlap_m", "tunnelled"]
    assert cols.index("wall_contact_steps") < cols.index("worker")
    plain = columns(["k"], rows)
    assert "max_overlap_m" not in plain and "wall_contact_steps" in plain


@pytest.mark.parametrize(
    "task_name, overrides, message",
    [
        ("cartpole-wall", ["metric_params.angle_block=nosuch"], "metric_params.angle_block"),
        ("cartpole-wall", ["metric_params.contact_pair=[tip]"], "metric_params.contact_pair"),
        ("cartpole-wall", ["metric_params.contact_pair=[tip, nosuch]"], "'nosuch'"),
        ("cartpole-wall", ["metric_params.camera=[1, 2]"], "metric_params.camera"),
        ("kinova-up", ["metric_params.object=nosuch"], "metric_params.object"),
        ("kinova-up", ["metric_params.object_target=[1, 2]"], "metric_params.object_target"),
        ("cheetah-trot-1.0", ["metric_params.feet=[a, b]"], "metric_params.feet"),
        ("cheetah-trot-1.0", ["metric_params.ground=nosuch"], "'nosuch'"),
        ("cheetah-trot-1.0", ["metric_params.body=nosuch"], "metric_params.body"),
    ],
)
def test_bad_metric_params_fail_before_any_solve(task_name, overrides, message, monkeypatch):
    from hydroilqr.solver import api

    def no_solve(*a, **k):
        raise AssertionError("solved")

    monkeypatch.setattr(api, "solve", no_solve)
    task = Task.load(task_name, overrides, smoke=True)
    with pytest.raises(ConfigError, match=message) as e:
        metrics.validate(task)
    assert "\n" not in str(e.value)
    with pytest.raises(ConfigError, match=message):
        validate_task(task)  # what solve, sweep and mpc run first


def test_object_metric_needs_a_body():
    task = Task.load("cartpole-wall", ["metrics=[default, object]"], smoke=True)
    with pytest.raises(ConfigError, match="metric_params.object"):
        metrics.validate(task)


def test_object_metric_with_a_fixed_target_and_its_plot(tmp_path, monkeypatch):
    from hydroilqr.metrics import objects

    task = Task.load(
        "kinova-up", ["metrics=[object]", "metric_params.object_target=[0.5, 0.1, 0.3]"], smoke=True
    )
    metrics.validate(task)
    pos = list(task.dynamics.layout.primitives["ball.position"].coords)
    X = np.tile(task.x0, (4, 1))
    p0 = X[0, pos].copy()
    X[1, pos] = p0 + [0.0, 0.0, 0.2]
    X[2, pos] = p0 + [0.1, 0.0, 0.05]
    X[3, pos] = p0 + [0.2, -0.1, 0.0]
    touching = [("ball_collision", "ball", "end_effector_link_collision", "end_effector_link", 3)]
    monkeypatch.setattr(
        objects, "contact_pairs", lambda dyn, x: touching if x[pos[2]] > p0[2] else []
    )
    sol = SimpleNamespace(t=0.1 * np.arange(4), X=X)
    m = metrics.compute(task, sol)
    np.testing.assert_allclose(m["ball_displacement_m"], [0.2, -0.1, 0.0], atol=1e-12)
    np.testing.assert_allclose(m["ball_target_m"], [0.5, 0.1, 0.3])
    err = p0 + [0.2, -0.1, 0.0] - [0.5, 0.1, 0.3]
    np.testing.assert_allclose(m["target_error_xyz_m"], err)  # every axis counts
    assert m["target_error_m"] == pytest.approx(np.linalg.norm(err))
    assert m["max_ball_height_gain_m"] == pytest.approx(0.2)
    assert m["contact_links"] == ["end_effector_link"] and m["contact_steps"] == {
        "end_effector_link": 2
    }
    assert m["max_robot_ball_faces"] == 3
    metrics.plot(task, sol, tmp_path)
    assert (tmp_path / "ball.png").stat().st_size > 5_000


def test_kinova_tasks_use_object_and_keep_their_keys():
    task = Task.load("kinova-forward", smoke=True)
    assert task.config.metrics == ["default", "object", "kinova"]
    sol = SimpleNamespace(t=0.01 * np.arange(3), X=np.tile(task.x0, (3, 1)))
    m = {
        **metrics.METRICS["object"].compute(task, sol),
        **metrics.METRICS["kinova"].compute(task, sol),
    }
    for key in (
        "ball_start_m",
        "ball_final_m",
        "ball_target_m",
        "ball_displacement_m",
        "target_error_m",
        "target_error_xyz_m",
        "max_ball_height_gain_m",
        "contact_links",
        "contact_steps",
        "max_arm_ball_faces",
    ):
        assert key in m, key
    assert m["max_arm_ball_faces"] == m["max_robot_ball_faces"]


def test_contact_timeline_pairs_intervals_and_forces(tmp_path):
    from hydroilqr.metrics import common
    from hydroilqr.metrics.contacts import contact_metrics
    from hydroilqr.model.contacts import touched_pairs

    task = Task.load("kinova-forward", ["num_steps=4"], smoke=True)
    U = task.initial_guess(4)
    X = task.dynamics.rollout(task.x0, U)
    sol = SimpleNamespace(t=0.01 * np.arange(5), X=X, U=U)
    before = common.default_metrics(task, sol)
    m = contact_metrics(task, sol)
    assert common.default_metrics(task, sol) == before  # no other value changes
    ball = [c for c in m["contacts"] if "ball" in c["bodies"] and "world" in c["bodies"]]
    assert ball, m["contacts"]
    c = ball[0]
    assert c["intervals"] == [[0.0, 0.04]] and c["steps"] == 5
    weight = 9.81 * task.dynamics.plant.GetBodyByName("ball").default_mass()
    assert 0.3 * weight < c["peak_normal_force_N"] < 10 * weight
    json.dumps(m)  # plain JSON
    metrics.plot(
        SimpleNamespace(
            name="t",
            config=SimpleNamespace(metrics=["contacts"], plant=task.config.plant),
            dynamics=task.dynamics,
        ),
        sol,
        tmp_path,
    )
    assert (tmp_path / "contacts.png").stat().st_size > 5_000
    touched = touched_pairs(task, steps=2)
    assert any(set(t["bodies"]) == {"ball", "world"} and t["steps"] == 3 for t in touched)


def test_contact_timeline_is_in_the_default_metric():
    from hydroilqr.model.contacts import runs

    assert runs(np.array([0, 1, 1, 0, 1], bool)) == [(1, 2), (4, 4)]
    task = Task.load("cartpole-wall", ["num_steps=3"], smoke=True)
    U = np.zeros((3, task.dynamics.nu))
    sol = SimpleNamespace(t=0.01 * np.arange(4), X=task.dynamics.rollout(task.x0, U), U=U)
    m = metrics.compute(task, sol)
    assert m["contacts"] == [] and "max_overlap_m" in m


def test_check_reports_touched_pairs(capsys):
    from hydroilqr.cli import main
    from hydroilqr.studies.check import check_task

    facts = check_task(Task.load("kinova-forward", smoke=True), 3)
    assert any(set(t["bodies"]) == {"ball", "world"} for t in facts["touched_pairs"])
    assert "ball" in facts["tracked_bodies"] and facts["tracked_objects"] == ["ball"]
    assert main(["check", "kinova-forward", "--smoke"]) == 0
    assert "pairs touching along the rollout" in capsys.readouterr().out


def test_savefig_writes_and_closes(tmp_path):
    from hydroilqr.io.figures import pyplot, savefig

    plt = pyplot()
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    assert savefig(fig, tmp_path / "f.png") == tmp_path / "f.png"
    assert (tmp_path / "f.png").stat().st_size > 1_000
    assert not plt.fignum_exists(fig.number)


def test_previous_plots_named_after_a_body_are_outputs(tmp_path):
    from hydroilqr.output import report

    summary = {"task": "t", "config": {"metrics": ["object"], "metric_params": {"object": "box"}}}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    (tmp_path / "box.png").write_bytes(b"x")
    (tmp_path / "contacts.png").write_bytes(b"x")
    (tmp_path / "mine.png").write_bytes(b"x")
    names = {p.name for p in report.solve_outputs(tmp_path)}
    assert {"box.png", "contacts.png", "summary.json"} <= names and "mine.png" not in names


def test_metric_decorator_registers_a_metric_of_ones_own(monkeypatch):
    monkeypatch.setattr(metrics, "METRICS", dict(metrics.METRICS))

    @metrics.metric("mine", files=("mine.png",))
    def mine(task, sol):
        return {"answer": 42}

    assert metrics.get("mine").compute is mine and "mine.png" in metrics.plot_files()
    task = Task.load("cartpole-wall", ["metrics=[mine]"], smoke=True)
    metrics.validate(task)
    assert metrics.compute(task, SimpleNamespace()) == {"answer": 42}


def test_check_warns_when_no_touched_pair_involves_a_tracked_object():
    from hydroilqr.model import contacts
    from hydroilqr.studies.check import _untracked_contact_warning

    task = Task.load("kinova-forward", smoke=True)
    assert {"ball", "shoulder_link"} <= contacts.tracked_bodies(task)
    assert contacts.tracked_objects(task) == {"ball"}  # the arm is moved by its motors
    fixed = contacts.fixed_bodies(task)
    assert "world" in fixed and "ball" not in fixed
    other = [{"pair": ["a", "b"], "bodies": ["world", "crate"], "steps": 2}]
    w = _untracked_contact_warning(other, {"ball"}, fixed)
    assert "involves ball" in w and contacts.NO_CONTACT_REMEDY in w
    assert "touches nothing" in _untracked_contact_warning([], {"ball"}, fixed)
    # resting on the ground is no contact that moves it (solve's no_progress test is the same)
    ground = [{"pair": ["ball", "ground"], "bodies": ["ball", "world"], "steps": 9}]
    assert "touches only what is fixed" in _untracked_contact_warning(ground, {"ball"}, fixed)
    touching = [{"pair": ["gripper", "ball"], "bodies": ["gripper", "ball"], "steps": 2}]
    assert _untracked_contact_warning(touching, {"ball"}, fixed) == ""
    # a robot's own links are no objects: no warning for a task without contact
    cartpole = Task.load("cartpole-wall", smoke=True)
    assert contacts.tracked_objects(cartpole) == set()
    assert _untracked_contact_warning([], contacts.tracked_objects(cartpole), fixed) == ""


def test_the_terminal_metrics_line_prints_arrays_fixed_point():
    """Not numpy's scientific notation; scalars as before (JSON keeps full precision)."""
    m = {
        "ball_final_m": np.array([7.99011324e-01, -5.43492901e-04, 9.57821572e-02]),
        "steps": 200,
        "final_gap_m": 0.012345678,
        "tunnelled": False,
        "tiny": np.array([-1e-9, 2.0]),
    }
    assert metrics.summary_lines(m)[0] == (
        "metrics: ball_final_m=[0.7990, -0.0005, 0.0958], steps=200, final_gap_m=0.01235, "
        "tunnelled=False, tiny=[0.0000, 2.0000]"
    )
    assert metrics.terminal_value(np.float32(0.5)) == "0.5"
    assert metrics.terminal_value([[1.0, 2.5], [3, None]]) == "[[1.0000, 2.5000], [3, None]]"


def test_the_command_limit_ratio_is_named_as_one_and_old_summaries_still_read():
    """Issue 39, 5: max |u| / limit is `max_command_to_limit_ratio`; a summary written under
    the earlier name `max_command_over_limit` still prints its note."""
    from hydroilqr.metrics import command_limit_ratio, summary_lines

    new = {"commands_beyond_limits": 3, "max_command_to_limit_ratio": 1.695,
           "max_command_to_limit_actuator": "joint_6"}  # fmt: skip
    old = {"commands_beyond_limits": 3, "max_command_over_limit": 1.695,
           "max_command_over_limit_actuator": "joint_6"}  # fmt: skip
    assert command_limit_ratio(new) == command_limit_ratio(old) == (1.695, "joint_6")
    assert command_limit_ratio({"commands_beyond_limits": 0}) is None
    for m in (new, old):
        note = [line for line in summary_lines(m) if line.startswith("note:")]
        assert note and "up to 1.7 times the limit, joint_6" in note[0]


def test_headline_names_a_number_once_when_two_metrics_share_it():
    m = {"target_error_m": 0.003, "max_ball_height_gain_m": 0.002}
    assert metrics.headline(["default", "object", "kinova"], m) == "ball err cm 0.3, lift cm 0.2"
