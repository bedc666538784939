"""problem/ (load, files, overrides, smoke and the sections): task files, overrides, --set,
extends, smoke sections, ranges."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from hydroilqr import Task
from hydroilqr.problem.errors import ConfigError
from tests.conftest import BASE, edit, write_case


@pytest.mark.parametrize(
    "override,needle",
    [
        ("horizon=0", "horizon: must be positive"),
        ("solver.line_search_factor=1.0", "solver.line_search_factor"),
        ("solver.regularization_max=1e-6", "solver.regularization_max"),  # = its min
        ("mpc.deadline=1.5", "mpc.deadline"),
        ("receding_horizon={window_steps: 4, shift_steps: 2, resolves: 2, max_iterations: 0}",
         "receding_horizon.max_iterations"),
        ("receding_horizon={window_steps: 4, shift_steps: 2, resolves: 2, rescue_factor: 0.5}",
         "receding_horizon.rescue_factor"),
        ("receding_horizon={window_steps: 4, shift_steps: 2, resolves: 2, rescue_factor: 2,"
         " rescue_iterations: 0}", "receding_horizon.rescue_iterations"),
        ("continuation=[{plant.time_step: 0.02}]", "cannot change between stages"),
    ],
)  # fmt: skip
def test_settings_that_cannot_run_are_refused(override, needle):
    from hydroilqr.problem.errors import ConfigError
    from hydroilqr.problem.load import load_task

    extra = ["solver.regularization_min=1e-6"] if "regularization_max" in override else []
    with pytest.raises(ConfigError, match=needle.replace(".", r"\.")):
        load_task("cartpole-wall", [*extra, override])


def test_settings_at_the_edges_of_their_ranges_are_accepted():
    from hydroilqr.problem.load import load_task

    ok = [
        "solver.short_step=0",  # 0 = always shrink after a success (documented)
        "receding_horizon={window_steps: 4, shift_steps: 4, resolves: 2}",  # whole window kept
        "cost.nominal_rate.cart_position=-0.5",  # a nominal moving backwards
    ]
    for o in ok:
        load_task("cartpole-wall", [o])
    # With num_steps the horizon is not used: it need not be whole steps of the time step.
    assert load_task("cartpole-wall", ["plant.time_step=0.03", "num_steps=5"]).steps == 5
    # 0.29 / 0.01 = 28.999999999999996: rounded, not truncated
    assert load_task("cartpole-wall", ["horizon=0.29"]).steps == 29
    # Whole floats for integers (e.g. a linspace sweep of solver.max_iterations)
    assert load_task("cartpole-wall", {"solver.max_iterations": 20.0}).solver.max_iterations == 20
    cfg = load_task("cartpole-wall", {"cost.running_cost_dt": "0"})
    assert cfg.cost.running_cost_dt is False
    assert load_task("cartpole-wall", {"cost.running_cost_dt": "1"}).cost.running_cost_dt is True


def test_a_child_task_num_steps_wins_over_its_base_horizon(tmp_path):
    from hydroilqr.problem.load import load_task

    urdf = "package://drake/examples/pendulum/Pendulum.urdf"
    (tmp_path / "base.yaml").write_text(
        f"models: [{{file: '{urdf}'}}]\nhorizon: 0.5\ncost: {{R: 0.1}}\n"
    )
    (tmp_path / "child.yaml").write_text("extends: base.yaml\nnum_steps: 3\n")
    assert load_task(str(tmp_path / "child.yaml")).steps == 3


def test_geometry_overrides_by_dotted_name_and_shorthand_errors():
    from hydroilqr.problem.errors import ConfigError
    from hydroilqr.problem.load import load_task

    cfg = load_task("cartpole-wall", ["geometry.my.tip.friction=0.3"])
    assert cfg.geometry["my.tip"].friction == 0.3  # a geometry name with a dot in it
    # A geometry the task names: a far-off key is reported against its contact properties.
    with pytest.raises(ConfigError, match=r"geometry\.tip\.youngs: unknown key"):
        load_task("cartpole-wall", ["tip.youngs=1e6"])  # (not a near-miss of a property)
    # A name that is both a scene object and a geometry entry is ambiguous.
    with pytest.raises(ConfigError, match="names both a scene object and a geometry entry"):
        load_task("cartpole-wall", ["geometry.wall.friction=0.3", "wall.dissipation=1"])


def test_a_member_given_after_its_group_overrides_it():
    """--set initial_state.joint_2=... over a task's group arm_q changes that joint only."""
    from hydroilqr import Task

    base = Task.load("kinova-forward", smoke=True)
    task = Task.load("kinova-forward", ["initial_state.joint_2=1.0"], smoke=True)
    j2 = task.dynamics.layout.block("joint_2").coords[0]
    assert task.x0[j2] == 1.0
    others = np.ones(task.dynamics.nx, bool)
    others[j2] = False
    np.testing.assert_array_equal(task.x0[others], base.x0[others])


def test_sibling_defaults_agree():
    """Linearizer and linearize read X the same way by default (not as a rollout of U);
    PlaybackSettings picks the CLI's default speed per policy; batch_step is step, batched."""
    from hydroilqr import Task
    from hydroilqr.control.playback import PlaybackSettings
    from hydroilqr.model.derivatives import Linearizer, batch_step, linearize

    task = Task.load("cartpole-wall", ["num_steps=5", "solver.derivatives=forward"])
    dyn = task.dynamics
    U = np.zeros((5, 1))
    X = dyn.rollout(task.x0, U) + 0.01  # not a rollout of U
    A1, B1 = linearize(dyn, X, U, "forward")
    A2, B2 = Linearizer.from_settings(dyn, task.config.solver)(X, U)
    np.testing.assert_array_equal(A1, A2)
    np.testing.assert_array_equal(B1, B2)
    assert PlaybackSettings(policy="ilqr").speed == 1.0 and PlaybackSettings().speed == 0.5
    nxt = batch_step(dyn, X[:5], U)
    np.testing.assert_array_equal(nxt[2], dyn.step(X[2], U[2]))


def test_extends_names_the_child_of_a_missing_parent_and_the_childs_smoke_length_wins(tmp_path):
    from hydroilqr import Task
    from hydroilqr.problem.errors import ConfigError
    from hydroilqr.problem.files import TASKS_DIR

    (tmp_path / "orphan.yaml").write_text("extends: nope.yaml\n")
    with pytest.raises(ConfigError, match="orphan.yaml: extends: no such file"):
        Task.load(str(tmp_path / "orphan.yaml"))
    (tmp_path / "parent.yaml").write_text(
        f"extends: {TASKS_DIR / 'cartpole-wall.yaml'}\nsmoke: {{num_steps: 25}}\n"
    )
    (tmp_path / "child.yaml").write_text("extends: parent.yaml\nname: c\nsmoke: {horizon: 0.3}\n")
    task = Task.load(str(tmp_path / "child.yaml"), smoke=True)
    assert task.steps == round(0.3 / task.config.plant.time_step)


def test_set_with_both_horizon_and_num_steps_is_refused_like_a_task_file():
    from hydroilqr import Task
    from hydroilqr.problem.errors import ConfigError

    with pytest.raises(ConfigError, match="horizon or num_steps, not both"):
        Task.load("cartpole-wall", ["horizon=0.3", "num_steps=7"])
    assert Task.load("cartpole-wall", ["horizon=0.3"]).steps == 30


def test_set_smoke_keys_change_what_smoke_applies():
    from hydroilqr import Task

    t = Task.load(
        "cartpole-wall", ["smoke.num_steps=5", "smoke.solver.max_iterations=2"], smoke=True
    )
    assert t.steps == 5 and t.config.solver.max_iterations == 2
    assert t.config.solver.derivatives == Task.load("cartpole-wall").config.solver.derivatives


def test_set_an_empty_path_means_none_not_the_working_directory(tmp_path, monkeypatch):
    from hydroilqr.problem.load import load_task

    monkeypatch.chdir(tmp_path)  # it became str(cwd): "cannot read <cwd>/solution.npz"
    cfg = load_task("cartpole-wall", ['cost.reference=""', 'mpc.warm_start_plan=""'])
    assert cfg.cost.reference == "" and cfg.mpc.warm_start_plan == ""


def test_set_smoke_length_or_whole_section_changes_what_smoke_applies():
    from hydroilqr.problem.errors import ConfigError
    from hydroilqr.problem.load import load_task

    # kinova's smoke section gives num_steps: 10; a --set smoke.horizon was silently ignored
    cfg = load_task("kinova-forward", ["smoke.horizon=0.05"], smoke=True)
    assert cfg.steps == round(0.05 / cfg.plant.time_step)
    assert load_task("cartpole-wall", ["smoke={num_steps: 3}"], smoke=True).steps == 3  # was 200
    with pytest.raises(ConfigError, match="smoke.horizon or smoke.num_steps, not both"):
        load_task("cartpole-wall", ["smoke.horizon=0.05", "smoke.num_steps=3"], smoke=True)


def test_overrides_and_shortcuts():
    task = Task.load(
        "cartpole-wall",
        ["tip.hydroelastic_modulus=3e5", "wall.friction=0.1", "solver.max_iterations=7"],
    )
    assert task.config.geometry["tip"].hydroelastic_modulus == 3e5
    assert task.config.scene[0].friction == 0.1
    assert task.config.solver.max_iterations == 7


def test_extends_across_directories_keeps_base_paths(tmp_path):
    """A base in another directory keeps resolving its own relative model and guess paths."""
    from hydroilqr.problem.load import load_task

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


def test_set_reaches_blocks_with_dots_in_their_names(tmp_path):
    """Velocity blocks (`shoulder.v`) and floating-body blocks (`ball.position`) by --set."""
    from hydroilqr.model.task import Task

    path = write_case(tmp_path, BASE)
    task = Task.load(
        str(path), ["cost.Q.shoulder.v=0.5", "initial_state.elbow=0.2", "cost.Qf.elbow.v=2"]
    )
    assert task.config.cost.Q == {"angles": 1.0, "shoulder.v": 0.5}  # merged, not replaced
    assert task.config.cost.Qf["elbow.v"] == 2
    v = task.dynamics.layout.block("shoulder.v").tangent[0]
    assert task.cost.q[v] == 0.5


def test_horizon_on_the_command_line_wins_over_num_steps(tmp_path):
    from hydroilqr.model.task import Task

    path = write_case(tmp_path, BASE)  # num_steps: 5
    assert Task.load(str(path), ["horizon=0.2"]).config.steps == 10


def test_geometry_keys_by_body_collision_name_or_both(tmp_path, capsys):
    """A collision name matches every geometry of that name, a body name all of the body's;
    a body name that is also another body's collision name is ambiguous; BODY/NAME picks one."""
    from hydroilqr.model.plant import geometry_hits

    geoms = {1: ("Sphere", "arm"), 2: ("Sphere", "base"), 3: ("arm", "base"), 4: ("Box", "arm")}
    assert geometry_hits("Sphere", geoms) == [1, 2]  # every geometry of that name
    assert geometry_hits("base/Sphere", geoms) == [2]
    from hydroilqr.problem.errors import ConfigError

    with pytest.raises(ConfigError, match="ambiguous"):
        geometry_hits("arm", geoms)  # body arm, and a collision named arm on base
    assert geometry_hits("Box", geoms) == [4]


def test_a_later_layer_horizon_wins_over_an_earlier_num_steps(tmp_path):
    from hydroilqr.problem.load import load_task

    path = write_case(tmp_path, BASE)  # num_steps: 5 at dt 0.02
    extra = tmp_path / "extra.yaml"
    extra.write_text("horizon: 0.2\n")
    assert load_task(str(path), config_file=str(extra)).steps == 10
    smoke = write_case(tmp_path, edit(smoke={"horizon": 0.06}))
    assert load_task(str(smoke), smoke=True).steps == 3
    (tmp_path / "child.yaml").write_text(f"extends: {path.name}\nhorizon: 0.4\n")
    assert load_task(str(tmp_path / "child.yaml")).steps == 20


def test_continuation_stages_keep_the_grid_and_read_paths_from_the_task_file(tmp_path):
    from hydroilqr.model.task import Task

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


def test_tamsi_is_refused_where_the_drake_has_none(monkeypatch, capsys):
    """Drake 1.57 removed TAMSI: there, tamsi is refused in one line before any work, naming
    the Drakes that have it; the check reads the bindings the installed Drake ships."""
    from pydrake.multibody.plant import DiscreteContactApproximation

    from hydroilqr import cli
    from hydroilqr.problem import capabilities
    from hydroilqr.problem import plant as plant_section
    from tests.conftest import assert_one_line

    assert capabilities.drake_has_tamsi() == hasattr(DiscreteContactApproximation, "kTamsi")
    monkeypatch.setattr(plant_section, "drake_has_tamsi", lambda: False)
    with pytest.raises(ConfigError, match=r"TAMSI.*Drake 1\.56 and older"):
        Task.load("cartpole-wall", ["plant.contact_approximation=tamsi"])
    Task.load("cartpole-wall", ["plant.contact_approximation=sap"])  # the others still load
    rc = cli.main(["solve", "cartpole-wall", "--set", "plant.contact_approximation=tamsi"])
    out, err = capsys.readouterr()
    assert_one_line(rc, out, err, "plant.contact_approximation=tamsi needs Drake's TAMSI")
