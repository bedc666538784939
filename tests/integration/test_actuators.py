"""Task actuators (effort limit, rotor inertia, gear ratio) and what uses them: the plant,
`check`, playback's PD+ stability advisory and its resting measurement (issue 28)."""

from __future__ import annotations

import numpy as np
import pytest

from hydroilqr import Task
from hydroilqr.control.playback import PlaybackSettings, _pd_check, actuated_joints, playback
from hydroilqr.model.plant import Dynamics
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.load import with_overrides
from tests.conftest import rollout_plan

NO_ROTORS = [f"actuators.joint_{i}.rotor_inertia=0" for i in range(1, 8)]


def test_effort_limit_override_reaches_the_plant_and_clips():
    task = Task.load("kinova-forward", ["actuators.joint_7.effort_limit=5"], smoke=True)
    dyn = task.dynamics
    assert dyn.effort_limits[6] == 5.0 and dyn.effort_limits[0] == 39.0
    x0 = task.x0
    u = dyn.gravity_compensation(x0)
    beyond, at = u.copy(), u.copy()
    beyond[6], at[6] = 50.0, 5.0
    np.testing.assert_array_equal(dyn.step(x0, beyond), dyn.step(x0, at))


def test_unknown_actuator_is_refused_with_the_valid_names():
    task = Task.load("kinova-forward", ["actuators.joint_8.effort_limit=5"], smoke=True)
    with pytest.raises(ConfigError) as e:
        _ = task.dynamics
    msg = str(e.value)
    assert "actuators.joint_8" in msg and "joint_1" in msg and "joint_7" in msg
    assert "\n" not in msg


@pytest.mark.parametrize(
    "key, value", [("effort_limit", 0), ("rotor_inertia", -1), ("gear_ratio", 0)]
)
def test_bad_actuator_values_are_refused(key, value):
    with pytest.raises(ConfigError, match=f"actuators.joint_7.{key}"):
        Task.load("kinova-forward", [f"actuators.joint_7.{key}={value}"], smoke=True)


def test_reflected_inertia_is_on_the_mass_matrix_and_calms_the_wrist_loop():
    task = Task.load("kinova-forward", smoke=True)
    bare = Dynamics(with_overrides(task.config, NO_ROTORS))
    geared = task.dynamics
    st = PlaybackSettings(speed=0.5)
    out = {}
    for label, dyn in (("bare", bare), ("geared", geared)):
        names, joints, _, _, vi, _ = actuated_joints(dyn.plant)
        out[label] = _pd_check(dyn, task.x0, joints, vi, st)
    a = geared.plant.get_joint_actuator(geared.plant.GetJointActuatorIndices()[6])
    rho_g2 = a.default_rotor_inertia() * a.default_gear_ratio() ** 2
    assert rho_g2 > 0
    j7 = out["geared"]["pd_loop"]["joint_7"]
    assert j7["inertia"] == pytest.approx(out["bare"]["pd_loop"]["joint_7"]["inertia"] + rho_g2)
    assert j7["reflected_inertia"] == pytest.approx(rho_g2)
    assert any(w.startswith("joint_7:") for w in out["bare"]["warnings"])
    assert out["geared"]["warnings"] == []


def test_check_lists_rotor_inertia_and_gear_ratio(capsys):
    from hydroilqr import cli

    assert cli.main(["check", "kinova-forward", "--set", "actuators.joint_7.effort_limit=5"]) == 0
    out = capsys.readouterr().out
    assert "rotor inertia" in out and "gear ratio" in out and "reflected" in out


def test_playback_measures_where_the_object_comes_to_rest():
    task = Task.load("kinova-forward", ["solver.autodiff_workers=1"], smoke=True)
    dyn = task.dynamics
    N = task.steps
    U = task.initial_guess(N)
    sol = rollout_plan(task, U)
    st = PlaybackSettings(speed=1.0, truth_time_step=0.002, rest_max=0.3, rest_time=0.05)
    r = playback(task, sol, st)
    m = r.metrics
    ob = m["object"]
    assert r.hold is not None and r.hold.X.shape[1] == dyn.nx
    assert len(r.hold.t) <= round(0.3 / 0.002)
    # the ball at rest on the floor: held arm, the ball never pushed
    assert ob["rest"]["actual"]["rested"] and ob["rest"]["planned"]["rested"]
    assert m["resting_gap_m"] == ob["resting_gap"] and m["final_gap_m"] == ob["final_gap"]
    assert ob["resting_gap"] < 0.01
    off = playback(task, sol, PlaybackSettings(speed=1.0, truth_time_step=0.002, rest_max=0))
    assert off.hold is None and off.metrics["resting_gap_m"] is None


def test_mpc_truth_counts_the_commands_it_clips_at_the_task_limits():
    from hydroilqr.control.mpc import Truth

    task = Task.load("kinova-forward", ["actuators.joint_7.effort_limit=2"], smoke=True)
    truth = Truth(task)
    assert truth.limits[6] == 2.0
    u = np.zeros(7)
    u[6] = 3.0
    _, applied = truth.step(task.x0, u, 0, [])
    assert applied[6] == 2.0 and (truth.saturated, truth.commands) == (1, 7)


def test_commands_beyond_the_effort_limits_are_reported():
    """Drake clips the actuation input to the effort limits (the same trajectory as a clipped
    command, partials zero beyond it); a plan whose commands exceed them says so."""
    from hydroilqr import Task
    from hydroilqr.metrics import beyond_limits, summary_lines

    task = Task.load("kinova-forward", ["solver.autodiff_workers=1"], smoke=True)
    dyn = task.dynamics
    lim = dyn.effort_limits
    N = task.steps
    U = task.initial_guess(N)
    assert beyond_limits(dyn, U) == {"commands_beyond_limits": 0}
    U[3, 5] = 2.5 * lim[5]
    U[4, 1] = -1.5 * lim[1]
    np.testing.assert_array_equal(  # the plant applies the limit
        dyn.rollout(task.x0, U), dyn.rollout(task.x0, np.clip(U, -lim, lim))
    )
    m = beyond_limits(dyn, U)
    assert m["commands_beyond_limits"] == 2
    assert m["max_command_to_limit_ratio"] == pytest.approx(2.5)
    assert (
        m["max_command_to_limit_actuator"]
        == dyn.plant.get_joint_actuator(dyn.plant.GetJointActuatorIndices()[5]).name()
    )
    assert any("exceed" in line for line in summary_lines(m))
