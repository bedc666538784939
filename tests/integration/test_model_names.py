"""Two models that share a body name (issue 54, item 1): Drake's acrobot, whose welded base is
``base_link``, nudging Drake's ``simple_cuboid``, whose free body is ``base_link`` too. Names
are scoped by the model where they collide, ``MODEL::NAME`` is taken everywhere a name is, and
the no-contact warning sees the cube as the tracked object."""

from __future__ import annotations

import copy

import pytest

from hydroilqr import Task
from hydroilqr.metrics import validate_task
from hydroilqr.problem.errors import ConfigError
from tests.conftest import ACROBOT

CUBE = "package://drake/examples/kuka_iiwa_arm/models/objects/simple_cuboid.urdf"

NUDGE = {
    "name": "acrobot-nudge",
    "models": [{"file": ACROBOT}, {"file": CUBE, "name": "cube"}],
    "scene": [
        {
            "name": "ground",
            "shape": "box",
            "size": [4, 4, 0.2],
            "xyz": [0, 0.25, -3.2],
            "compliance": "compliant",
            "hydroelastic_modulus": 1.0e6,
        }
    ],  # fmt: skip
    "plant": {"time_step": 0.01},
    "num_steps": 10,
    "initial_state": {"base_link.position": [0.12, 0.25, -3.07]},
    "cost": {
        "Q": {"shoulder": 0.1, "elbow": 0.1},
        "R": 0.01,
        "Qf": {"base_link.position": 1000.0},
        "nominal": {"base_link.position": [0.32, 0.25, -3.07]},
    },
    "metrics": ["default", "object"],
    "metric_params": {"object": "cube::base_link", "object_target": [0.32, 0.25, -3.07]},
}


def _task(**changes) -> Task:
    spec = copy.deepcopy(NUDGE)
    for key, value in changes.items():
        node = spec
        *path, last = key.split("__")
        for p in path:
            node = node.setdefault(p, {})
        node[last] = value
    task = Task.from_dict(spec)
    task.validate()
    validate_task(task)  # the metrics' names too, as check and solve do
    return task


@pytest.fixture(scope="module")
def nudge() -> Task:
    return _task()


def test_shared_body_names_are_scoped_and_the_cube_is_the_tracked_object(nudge):
    from hydroilqr.model.contacts import fixed_bodies, tracked_objects
    from hydroilqr.studies.check import check_task

    bodies = {b for _, b in nudge.dynamics.geometry_names().values()}
    assert {"Acrobot::base_link", "cube::base_link", "lower_link"} <= bodies
    assert "base_link" not in bodies  # never the bare, ambiguous name
    assert "cube::base_link.position" in nudge.dynamics.layout.names()
    assert tracked_objects(nudge) == {"cube::base_link"}
    assert {"world", "Acrobot::base_link"} <= fixed_bodies(nudge)
    f = check_task(nudge, rollout_steps=5)
    assert f["cost_pull"] is None  # its guess is zeros: nothing for the cost to pull
    warned = [w for w in f["warnings"] if "touches only what is fixed to the world" in w]
    assert warned and "cube::base_link" in warned[0], f["warnings"]
    assert any("cube::base_link" in str(p) for p in f["pairs"])  # the table names the model


def test_model_scoped_names_work_in_every_section(nudge):
    """MODEL::NAME as a state block, a cost weight, a geometry key (body, collision, and
    BODY/COLLISION), a scene's no_contact_with and a metric's object; the bare name of the
    cube's blocks still works (no other block has it)."""
    layout = nudge.dynamics.layout
    assert layout.block("base_link.position") is layout.block("cube::base_link.position")
    assert layout.block("Acrobot::shoulder") is layout.block("shoulder")
    task = _task(
        initial_state={"cube::base_link.position.x": 0.13},
        cost__Q={"Acrobot::shoulder": 0.2, "elbow": 0.1},
        geometry={
            "cube::base_link": {"friction": 0.4},
            "Acrobot::base_link/base_link_collision": {"friction": 0.3},
        },
        metric_params={"object": "base_link"},
    )  # fmt: skip
    assert task.x0[layout.block("cube::base_link.position.x").coords[0]] == pytest.approx(0.13)
    inspector = task.dynamics.scene_graph.model_inspector()
    for gid, (_name, body) in task.dynamics.geometry_names().items():
        friction = inspector.GetProximityProperties(gid).GetPropertyOrDefault(
            "material", "coulomb_friction", None
        )
        if body == "cube::base_link":
            assert friction.static_friction() == pytest.approx(0.4)
        if body == "Acrobot::base_link":
            assert friction.static_friction() == pytest.approx(0.3)
    task = _task(
        cost__R={"Acrobot::elbow": 0.02}, actuators={"Acrobot::elbow": {"effort_limit": 5}}
    )
    assert task.cost.r.tolist() == [0.02] and task.dynamics._effort_limits().tolist() == [5.0]
    scene = copy.deepcopy(NUDGE["scene"])
    scene[0]["no_contact_with"] = ["cube::base_link"]
    _task(scene=scene)


@pytest.mark.parametrize(
    ("changes", "words"),
    [
        ({"geometry": {"base_link": {"friction": 0.5}}},
         ["names the bodies Acrobot::base_link, cube::base_link"]),
        ({"geometry": {"cube::nothing": {"friction": 0.5}}}, ["known:", "cube::base_link"]),
        ({"metric_params": {"object": "nothing"}},
         ["no floating body named 'nothing'", "floating bodies: cube::base_link"]),
        ({"metric_params": {"object": "Acrobot::base_link"}}, ["floating bodies: cube::base_link"]),
        ({"cost": {"R": 0.01, "Q": {"cube::shoulder": 1.0}}}, ["unknown state block", "known:"]),
    ],
)  # fmt: skip
def test_unknown_or_ambiguous_names_list_the_known_ones(changes, words):
    with pytest.raises(ConfigError) as e:
        _task(**changes)
    assert all(w in str(e.value) for w in words), str(e.value)


def test_contacts_plot_labels_name_the_model_of_a_shared_body():
    from hydroilqr.metrics.contacts import pair_label

    label = pair_label(("Box", "ground"), ("cube::base_link", "world"))
    assert label == "Box (cube::base_link) / ground"
    assert pair_label(("tip", "wall"), ("pole", "world")) == "tip / wall"


def test_printed_numbers_carry_their_units(nudge):
    """Issue 54, item 9: final errors per Qf block and check's max |v| with their units."""
    from hydroilqr.metrics import final_error_units, summary_lines
    from hydroilqr.metrics.common import block_unit
    from hydroilqr.studies.check import check_task

    dyn = nudge.dynamics
    units = {
        "shoulder": " rad",
        "elbow.v": " rad/s",
        "cube::base_link.position": " m",
        "base_link.velocity.z": " m/s",
        "base_link.angular_velocity": " rad/s",
        "base_link.orientation": " (2 sin(θ/2))",
    }
    assert {k: block_unit(dyn, k) for k in units} == units
    mixed = _task(blocks={"both": ["shoulder", "base_link.position.x"]})
    assert block_unit(mixed.dynamics, "both") == " (mixed units)"
    m = {"final_error": {"base_link.position": 0.2, "shoulder": 0.01}}
    line = summary_lines(m, final_error_units(nudge, m))[-1]
    assert line.endswith("base_link.position=0.2 m, shoulder=0.01 rad"), line
    f = check_task(nudge, rollout_steps=5)
    assert f["max_speed_unit"] in ("m/s", "rad/s") and f["max_speed_coordinate"]


def test_a_weld_parent_takes_model_scoped_frame_names():
    """A frame two models share is named MODEL::FRAME as a weld's parent too (the cube's
    base_link welded to the acrobot's); an unknown scoped parent is one line naming the key."""
    spec = copy.deepcopy(NUDGE)
    spec["models"][0]["name"] = "acrobot"
    spec["models"][1]["weld"] = {"parent": "acrobot::base_link", "child": "base_link"}
    spec.pop("metric_params")
    spec["metrics"] = ["default"]
    spec.pop("initial_state")
    spec["cost"] = {"Q": {"shoulder": 0.1}, "R": 0.01, "Qf": {"shoulder": 1.0}}
    assert Task.from_dict(spec).dynamics.nq == 2  # the cube is welded: only the acrobot moves
    spec["models"][1]["weld"]["parent"] = "nobody::base_link"
    with pytest.raises(ConfigError, match="parent: unknown frame 'nobody::base_link'"):
        _ = Task.from_dict(spec).dynamics
