"""Components of multi-coordinate blocks by name (issue 36): a planar joint's ``base.x`` and a
floating body's ``ball.position.z`` in initial_state, cost, nominal, groups, metrics and goals."""

from __future__ import annotations

import numpy as np
import pytest

from hydroilqr import Task
from hydroilqr.metrics import compute, validate_task
from hydroilqr.metrics.goals import evaluate
from hydroilqr.problem.errors import ConfigError

URDF = """<?xml version="1.0"?>
<robot name="slider">
  <link name="sled">
    <inertial><mass value="1.0"/>
      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
  </link>
  <joint name="base" type="planar">
    <parent link="world"/><child link="sled"/><axis xyz="0 0 1"/>
  </joint>
  <link name="arm">
    <inertial><origin xyz="0.1 0 0"/><mass value="0.1"/>
      <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial>
  </link>
  <joint name="spin" type="revolute">
    <parent link="sled"/><child link="arm"/><axis xyz="0 0 1"/>
    <limit effort="1.0" lower="-3" upper="3" velocity="10"/>
  </joint>
  <transmission type="SimpleTransmission" name="spin_tr">
    <actuator name="spin"/><joint name="spin"/><mechanicalReduction>1</mechanicalReduction>
  </transmission>
  <link name="ball">
    <inertial><mass value="0.1"/>
      <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial>
  </link>
</robot>
"""


def _task(tmp_path, **extra) -> Task:
    (tmp_path / "slider.urdf").write_text(URDF)
    data = {
        "models": [{"file": "slider.urdf"}],
        "plant": {"gravity": [0.0, 0.0, 0.0]},
        "num_steps": 5,
        "initial_state": {"base.y": 0.3, "ball.position.z": 1.0, "ball.velocity.x": 0.5},
        "cost": {"Qf": {"base.x": 10.0, "ball.position.z": 2.0}, "nominal": {"base.x": 1.0}},
        **extra,
    }
    return Task.from_dict(data, base_dir=tmp_path)


def test_components_resolve_to_drakes_coordinates(tmp_path):
    task = _task(tmp_path)
    plant, layout = task.dynamics.plant, task.dynamics.layout
    names = plant.GetStateNames(False)  # e.g. slider_base_x, ..., slider_base_vx
    for block, drake in [
        ("base.x", "base_x"),
        ("base.y", "base_y"),
        ("base.qz", "base_qz"),
        ("base.vx", "base_vx"),
        ("base.wz", "base_wz"),
        ("ball.position.z", "ball_z"),
        ("ball.velocity.x", "ball_vx"),
        ("ball.angular_velocity.y", "ball_wy"),
    ]:
        (i,) = layout.block(block).coords
        assert names[i].endswith(drake), (block, names[i])
    # components are addressable but not listed among the blocks (check's table)
    assert "base.x" not in layout.names() and "base" in layout.names()
    x0 = task.x0
    assert x0[layout.block("base.y").coords[0]] == 0.3
    assert x0[layout.block("ball.position.z").coords[0]] == 1.0
    assert x0[layout.block("ball.velocity.x").coords[0]] == 0.5


def test_cost_and_nominal_on_a_component_weigh_that_coordinate_alone(tmp_path):
    task = _task(tmp_path)
    cost, layout = task.cost, task.dynamics.layout
    qf = np.asarray(cost.qf)
    assert qf[layout.block("base.x").tangent[0]] == 10.0
    assert qf[layout.block("ball.position.z").tangent[0]] == 2.0
    assert np.count_nonzero(qf) == 2
    assert cost.x_nom[layout.block("base.x").coords[0]] == 1.0
    assert np.count_nonzero(cost.x_nom[: layout.nq]) == 2  # base.x and the ball's qw


def test_final_error_and_goal_on_a_component(tmp_path):
    from types import SimpleNamespace

    task = _task(tmp_path, goal={"final_error.base.x": {"max": 0.5}})
    validate_task(task)
    dyn = task.dynamics
    U = np.zeros((5, dyn.nu))
    X = dyn.rollout(task.x0, U)
    sol = SimpleNamespace(t=dyn.dt * np.arange(6), X=X, U=U, extra={}, costs=[0.0])
    m = compute(task, sol)
    assert m["final_error"]["base.x"] == pytest.approx(1.0)  # the sled stays at x = 0
    # no gravity: the ball stays at z = 1 (its nominal: 0)
    assert m["final_error"]["ball.position.z"] == pytest.approx(1.0)
    result = evaluate(task.config.goal, m)
    assert not result["met"] and result["checks"][0]["value"] == pytest.approx(1.0)


def test_groups_of_components_and_unknown_components(tmp_path):
    task = _task(tmp_path, blocks={"xy": ["base.x", "base.y"]})
    layout = task.dynamics.layout
    assert layout.block("xy").coords == (
        layout.block("base.x").coords[0],
        layout.block("base.y").coords[0],
    )
    with pytest.raises(ConfigError, match=r"cost.Q.base.w: unknown state block .*components"):
        validate_task(_task(tmp_path, **{"cost": {"Q": {"base.w": 1.0}}}))


def test_nominal_relative_to_the_start_and_a_rate_that_stops(tmp_path):
    cost_cfg = {
        "Qf": {"base.x": 1.0, "base.y": 1.0},
        "nominal": {"base.y": 0.2},  # an offset for base.y, relative to the start
        "nominal_rate": {"base.x": 1.0},
        "nominal_rate_until": 0.02,
        "nominal_relative_to_start": ["base.y", "ball.position"],
    }
    task = _task(tmp_path, cost=cost_cfg)
    validate_task(task)
    layout, x0 = task.dynamics.layout, task.x0
    (ix,), (iy,) = layout.block("base.x").coords, layout.block("base.y").coords
    ball = list(layout.block("ball.position").coords)
    xn = task.cost.nominal(np.array([0.0, 0.01, 0.05, 1.0]))
    assert xn[:, iy] == pytest.approx(0.3 + 0.2)  # the start's 0.3 plus the offset
    np.testing.assert_allclose(xn[:, ball], np.tile(x0[ball], (4, 1)))  # stay where it starts
    np.testing.assert_allclose(xn[:, ix], [0.0, 0.01, 0.02, 0.02])  # the rate stops at 0.02 s


@pytest.mark.parametrize(
    "cost, message",
    [
        ({"nominal_rate_until": -1.0}, r"cost.nominal_rate_until: expected a time >= 0"),
        ({"nominal_relative_to_start": ["nope"]}, r"cost.nominal_relative_to_start.nope: unknown"),
        (
            {"nominal_relative_to_start": ["ball.orientation"]},
            r"cost.nominal_relative_to_start.ball.orientation: not supported for orientations",
        ),
    ],
)
def test_bad_relative_nominals_and_rate_ends_are_one_line_errors(tmp_path, cost, message):
    with pytest.raises(ConfigError, match=message):
        validate_task(_task(tmp_path, cost={"Qf": {"base.x": 1.0}, **cost}))
