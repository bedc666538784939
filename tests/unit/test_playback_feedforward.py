"""control.playback: the PD+ feed-forward, dynamically scaled to the playback speed or not."""

from __future__ import annotations

import numpy as np
import pytest

from hydroilqr.control.playback import PlanSampler, PlaybackSettings, feedforward, playback
from hydroilqr.model.task import Task
from hydroilqr.problem.errors import ConfigError
from tests.conftest import rollout_plan, write_task


@pytest.fixture(scope="module")
def acrobot(tmp_path_factory):
    """The tiny acrobot task (gravity loads its actuated elbow) and a hand-made plan on it:
    a rollout of a swinging elbow torque, no solve."""
    task = Task.load(
        str(
            write_task(
                tmp_path_factory.mktemp("acro"), num_steps=10, initial_state={"angles": [1.0, 0.5]}
            )
        )
    )
    N = task.steps
    U = np.array([[2.0 * np.sin(0.7 * k)] for k in range(N)])
    return task, rollout_plan(task, U, cost=0.0)


def _settings(**kw):
    return PlaybackSettings(truth_time_step=0.002, rest_max=0.0, **kw)


def test_scaled_and_plan_feedforward_send_the_same_commands_at_speed_1(acrobot):
    task, sol = acrobot
    g = task.dynamics.gravity_compensation(sol.X[3])
    assert np.abs(g).max() > 0.1  # g + 1·(ū − g) would round: this model tells them apart
    scaled = playback(task, sol, _settings(speed=1.0))
    plan = playback(task, sol, _settings(speed=1.0, feedforward="plan"))
    assert scaled.settings.feedforward == "scaled"  # the default
    assert np.array_equal(scaled.U, plan.U) and np.array_equal(scaled.X, plan.X)
    assert np.array_equal(scaled.reference.u, plan.reference.u)


def test_at_half_speed_the_held_feedforward_is_gravity_plus_a_quarter_of_the_rest(acrobot):
    task, sol = acrobot
    dyn, s = task.dynamics, 0.5
    r = playback(task, sol, _settings(speed=s))
    bare = playback(task, sol, _settings(speed=s, feedforward="plan"))
    ref = r.reference
    assert len(ref.t) == 20  # every 20 ms over the 0.2 s plan played in 0.4 s
    plan = PlanSampler(sol, [])
    for i, tr in enumerate(ref.t):
        xr, u_plan = plan.state(s * tr), dyn.clip_to_limits(plan.input(s * tr))
        g = dyn.gravity_compensation(xr)
        np.testing.assert_allclose(ref.u[i], g + 0.25 * (u_plan - g), rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(bare.reference.u[i], u_plan)
    assert not np.allclose(ref.u, bare.reference.u)
    # the PD+ law adds its terms to the held, scaled ū (reference row 1 from 0.02 s)
    st, k, qi, vi = r.settings, 10, r.q_indices, r.v_indices
    u = ref.u[1] - st.kp * (r.X[k, qi] - ref.q[1]) - st.kd * (r.X[k, vi] - ref.v[1])
    np.testing.assert_allclose(r.U[k], u)
    # the reference exported for --policy ilqr (no PD+ loop) is built the same way
    il = playback(task, sol, _settings(speed=s, policy="ilqr"))
    np.testing.assert_allclose(il.reference.u[: len(ref.t)], ref.u, rtol=0, atol=0)


def test_feedforward_blends_gravity_and_the_clipped_plan_input(acrobot):
    task, sol = acrobot
    dyn = task.dynamics
    x = sol.X[4]
    g = dyn.gravity_compensation(x)
    u = np.array([5.0])
    for s in (0.5, 2.0):
        st = PlaybackSettings(speed=s)
        np.testing.assert_allclose(feedforward(dyn, u, x, st), g + s * s * (u - g), rtol=1e-14)
    np.testing.assert_array_equal(
        feedforward(dyn, u, x, PlaybackSettings(speed=0.5, feedforward="plan")), u
    )


def test_an_unknown_feedforward_is_refused_in_one_line():
    with pytest.raises(ConfigError) as e:
        PlaybackSettings(feedforward="scale").validate()
    assert str(e.value) == "playback feedforward: expected scaled or plan, got 'scale'"
    PlaybackSettings(feedforward="plan").validate()


def test_damping_laws_of_the_contact_approximations():
    from hydroilqr.control.playback import damping_law, damping_note

    assert damping_law("sap") == "relaxation_time"
    assert {damping_law(a) for a in ("similar", "lagged", "tamsi")} == {"hunt_crossley"}
    assert damping_note("similar", "lagged") is None and damping_note("sap", "sap") is None
    assert "Hunt-Crossley dissipation" in damping_note("similar", "sap")
