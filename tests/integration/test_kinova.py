"""Kinova Gen3 whole-arm manipulation (paper §IV-B): model and smoke-sized solves."""

import numpy as np
import pytest

from hydroilqr import Task
from hydroilqr.metrics import compute
from hydroilqr.solver.loop import solve as ilqr_solve

TASKS = ["kinova-forward", "kinova-left", "kinova-up"]


@pytest.fixture(scope="module")
def forward():
    return Task.load("kinova-forward", smoke=True)


def test_model_mass_and_joints(forward):
    dyn = forward.dynamics
    plant = dyn.plant
    arm = plant.GetModelInstanceByName("gen3")
    ball = plant.GetModelInstanceByName("ball")
    mass = sum(plant.get_body(b).default_mass() for b in plant.GetBodyIndices(arm))
    assert mass == pytest.approx(9.0885, abs=0.01)  # 8 links + 0.9 kg gripper stand-in
    assert sum(plant.get_body(b).default_mass() for b in plant.GetBodyIndices(ball)) == (
        pytest.approx(0.258)
    )
    assert dyn.nu == 7 and plant.num_actuated_dofs(arm) == 7
    assert (dyn.nq, dyn.nv) == (14, 13)  # 7 joints + ball quaternion/position
    blocks = {
        b: len(dyn.layout.block(b).tangent)
        for b in (
            "arm_q",
            "ball_orientation",
            "ball_position",
            "arm_v",
            "ball_angular_velocity",
            "ball_velocity",
        )
    }
    assert blocks == {
        "arm_q": 7,
        "ball_orientation": 3,
        "ball_position": 3,
        "arm_v": 7,
        "ball_angular_velocity": 3,
        "ball_velocity": 3,
    }


def test_paper_cost_and_targets():
    up = Task.load("kinova-up")
    assert up.config.steps == 50 and up.config.plant.time_step == 0.01
    pos = up.dynamics.layout.block("ball_position")
    # Terminal ball weight 1000 (paper 100) with the paper code's dt-scaled running cost.
    np.testing.assert_allclose(up.cost.qf[list(pos.tangent)], [0, 0, 1000])
    assert up.config.cost.running_cost_dt
    z0, zn = up.x0[pos.coords[2]], up.cost.x_nom[pos.coords[2]]
    assert zn - z0 == pytest.approx(0.2)
    fwd = Task.load("kinova-forward")
    d = fwd.cost.x_nom[list(pos.coords)] - fwd.x0[list(pos.coords)]
    np.testing.assert_allclose(d, [0.2, 0, 0], atol=1e-12)
    assert fwd.config.cost.R == 0.01  # R = 0.01 I, times dt in the running cost
    assert fwd.cost.r == pytest.approx(np.full(7, 0.01 * 0.01))


def test_up_start_touches_ball_with_several_links():
    """The lifting start posture puts base, forearm and both wrist links within 1.5 mm."""
    from hydroilqr.model.plant import collision_geometries

    up = Task.load("kinova-up")
    dyn = up.dynamics
    dyn.plant.SetPositionsAndVelocities(dyn.plant_context, up.x0)
    sg = dyn.scene_graph
    query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(dyn.context))
    names = collision_geometries(dyn.plant, sg)
    near = set()
    for p in query.ComputeSignedDistancePairwiseClosestPoints(0.0015):
        bodies = {names[p.id_A][1], names[p.id_B][1]}
        if "ball" in bodies:
            near |= bodies - {"ball", "world"}
    assert {"base_link", "forearm_link", "spherical_wrist_1_link", "spherical_wrist_2_link"} <= near


@pytest.mark.parametrize("name", TASKS)
def test_smoke_solve_decreases_cost(name):
    task = Task.load(name, smoke=True)
    N = task.config.steps
    sol = ilqr_solve(task.problem(), task.initial_guess(N), task.config.solver, final_gains=False)
    assert sol.costs[-1] < sol.costs[0]
    m = compute(task, sol)
    pos = list(task.dynamics.layout.block("ball_position").coords)
    np.testing.assert_allclose(m["ball_displacement_m"], sol.X[-1, pos] - sol.X[0, pos])
    assert np.isfinite(m["target_error_m"]) and m["target_error_m"] >= 0
    plant = task.dynamics.plant
    arm = plant.GetModelInstanceByName("gen3")
    links = {plant.get_body(b).name() for b in plant.GetBodyIndices(arm)}
    assert set(m["contact_links"]) <= links  # arm links only (not the ball, nor the ground)
