"""Hardware-style playback (issue 6): PD+ on a finer 'real' simulation of a smoke solution."""

import csv
import json

import numpy as np
import pytest

from hydroilqr.control.playback import PlaybackSettings, advisories, load_run, playback
from hydroilqr.model.task import Task
from hydroilqr.output import results
from hydroilqr.problem.errors import ConfigError
from hydroilqr.solver.api import solve
from tests.conftest import rollout_plan


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    task = Task.load(
        "cartpole-wall",
        # (the pole at rest, the paper's start: these tests are about tracking, not impacts)
        [
            "num_steps=50",
            "solver.max_iterations=8",
            "cost.running_cost_dt=false",
            "initial_state.pole_angular_velocity=0",
        ],
        smoke=True,
    )
    sol = solve(task)
    out = tmp_path_factory.mktemp("cp")
    results.write_solve(task, sol, out, replay=False)
    return out


def test_pd_playback_tracks_the_joints(run_dir):
    run = load_run(run_dir)
    task, sol, _ = run
    assert run.solution is sol and run.task is task and run.summary["task"] == task.name
    r = playback(task, sol, PlaybackSettings(speed=1.0, truth_time_step=0.002))
    assert r.truth_contact == "similar" and r.planner_contact == "sap"
    assert r.X.shape == (round(0.5 / 0.002) + 1, 4) and np.all(np.isfinite(r.X))
    m = r.metrics
    cart = m["joint_tracking"]["cart_slider"]
    assert np.isfinite(cart["rms_error"]) and cart["rms_error"] < 0.02  # m
    assert m["object"]["name"] == "pole_pin" and m["object"]["kind"] == "joint"
    assert np.isfinite(m["object"]["final_gap"])
    # Reference held every 20 ms over the 0.5 s plan.
    assert len(r.reference.t) == 25 and r.reference.q.shape == (25, 1)
    # Half speed: twice as long, velocity reference halved.
    r2 = playback(task, sol, PlaybackSettings(speed=0.5, truth_time_step=0.002))
    assert r2.t[-1] == pytest.approx(1.0)
    np.testing.assert_allclose(r2.reference.v[5], 0.5 * sol.X[5, 2], rtol=1e-9, atol=1e-12)
    assert r2.settings.feedforward == "scaled"  # ū scaled to the speed by default
    assert r2.metrics["joint_tracking"]["cart_slider"]["rms_error"] < 0.1


def test_ilqr_policy_on_the_planner_model_reproduces_the_plan(run_dir):
    task, sol, _ = load_run(run_dir)
    st = PlaybackSettings(
        policy="ilqr",
        speed=1.0,
        truth_time_step=task.config.plant.time_step,
        truth_contact=task.config.plant.contact_approximation,
    )
    r = playback(task, sol, st)
    np.testing.assert_allclose(r.X, sol.X, atol=1e-9)
    assert r.metrics["object"]["final_gap"] < 1e-9
    # the exported reference is the one the pd policy sends (it had one more row at the end)
    pd = playback(task, sol, PlaybackSettings(speed=1.0, truth_time_step=st.truth_time_step))
    np.testing.assert_allclose(r.reference.t, pd.reference.t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.reference.u, pd.reference.u, rtol=0, atol=1e-12)


def test_cli_playback_writes_outputs(run_dir, tmp_path, capsys):
    from hydroilqr.cli import main

    out = tmp_path / "pb"
    assert (
        main(
            [
                "playback",
                str(run_dir),
                "--speed",
                "1",
                "--truth-time-step",
                "0.002",
                "--no-replay",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    # The PD+ policy's warning (the pole is unactuated) goes to stderr, the report to stdout.
    cap = capsys.readouterr()
    assert "warning:" in cap.err and "unactuated" in cap.err and "warning:" not in cap.out
    assert "truth steps in" in cap.out
    data = json.loads((out / "playback.json").read_text())
    for key in ("object", "joint_tracking", "settings", "truth", "saturated_fraction"):
        assert key in data
    assert (out / "playback.png").stat().st_size > 0
    with open(out / "reference.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["time_s", "q_cart_slider_m", "v_cart_slider_m_per_s", "u_cart_slider_N"]
    assert len(rows) == 26 and float(rows[2][0]) == pytest.approx(0.02)
    # Bad input: one line, non-zero exit, no traceback.
    assert main(["playback", str(tmp_path / "nothing")]) == 2
    assert main(["playback", str(run_dir), "--speed", "0", "--no-replay", "--out", str(out)]) == 2


def test_settings_are_validated():
    with pytest.raises(ConfigError):
        PlaybackSettings(policy="lqr").validate()
    with pytest.raises(ConfigError):
        PlaybackSettings(update_period=-1).validate()


def test_playback_warns_about_underactuation_and_slowed_ilqr(run_dir):
    task, sol, _ = load_run(run_dir)
    pd = playback(task, sol, PlaybackSettings(speed=1.0, truth_time_step=0.002))
    assert any("unactuated joints (pole_pin)" in w for w in pd.metrics["warnings"])
    # The PD+ loop runs on truth steps: a 1 kHz request with 2 ms steps runs at 500 Hz.
    assert pd.metrics["pd_loop_rate_hz"] == pytest.approx(500.0)
    # (Slowed down, the iLQR policy diverges on this plan: the warning is known beforehand.)
    plant = task.dynamics.plant
    assert "speed 0.5" in advisories(plant, PlaybackSettings(policy="ilqr", speed=0.5))[0]
    same = playback(task, sol, PlaybackSettings(policy="ilqr", speed=1.0, truth_time_step=0.002))
    assert not same.metrics["warnings"]


def test_playback_settings_that_cannot_fit_the_plan(run_dir):
    task, _, _ = load_run(run_dir)
    with pytest.raises(ConfigError, match="coarser than the plan's time step"):
        PlaybackSettings(truth_time_step=0.05).check_against(task)
    with pytest.raises(ConfigError, match="--truth-set solver.max_iterations"):
        PlaybackSettings(truth_overrides=["solver.max_iterations=1"]).check_against(task)
    PlaybackSettings(truth_overrides=["tip.friction=0.3"]).check_against(task)  # a shorthand
    # Playback's own options set these; a --truth-set of them would be half applied.
    with pytest.raises(ConfigError, match="playback sets it with --truth-time-step"):
        PlaybackSettings(truth_overrides=["plant.time_step=0.002"]).check_against(task)
    with pytest.raises(ConfigError, match="playback sets it with --truth-contact"):
        PlaybackSettings(truth_overrides=["plant.contact_approximation=tamsi"]).check_against(task)


def test_pd_loop_runs_at_the_rate_it_reports_and_the_api_checks_settings(run_dir):
    task, sol, _ = load_run(run_dir)
    st = PlaybackSettings(speed=1.0, truth_time_step=0.001, rate=300.0)
    r = playback(task, sol, st)
    changes = np.flatnonzero(np.any(np.diff(r.U, axis=0) != 0, axis=1)) + 1
    gaps = set(np.diff(changes).tolist())
    assert gaps <= {4} and r.metrics["pd_loop_rate_hz"] == pytest.approx(250.0)
    with pytest.raises(ConfigError, match="playback sets it with --truth-time-step"):
        playback(task, sol, PlaybackSettings(truth_overrides=["plant.time_step=0.01"]))


def test_ilqr_playback_applies_feedback(run_dir):
    from hydroilqr.control.playback import PlaybackSettings, load_run, playback

    task, sol, _ = load_run(run_dir)
    r = playback(task, sol, PlaybackSettings(policy="ilqr", speed=1.0, truth_time_step=0.002))
    dx = r.X[5] - sol.X[1]  # 0.01 s: plan step 1, the truth has drifted from the plan
    assert np.abs(dx).max() > 0
    np.testing.assert_allclose(r.U[5], sol.U[1] - sol.K[1] @ dx)


def test_pd_law_uses_kp_and_kd(run_dir):
    from hydroilqr.control.playback import PlaybackSettings, load_run, playback

    task, sol, _ = load_run(run_dir)
    st = PlaybackSettings(speed=1.0, truth_time_step=0.002)
    r = playback(task, sol, st)
    ref, k = r.reference, 10  # tau = 0.02 s: reference row 1
    qi, vi = r.q_indices, r.v_indices
    u = ref.u[1] - st.kp * (r.X[k, qi] - ref.q[1]) - st.kd * (r.X[k, vi] - ref.v[1])
    np.testing.assert_allclose(r.U[k], u)


def test_replay_frames_use_the_solved_inputs_and_the_nearest_state(monkeypatch, tmp_path):
    from hydroilqr.output import replay

    real_build = replay.build_diagram
    fixed = []

    class Port:
        def __init__(self, port):
            self.port = port

        def FixValue(self, context, value):
            fixed.append(np.array(value, dtype=float))
            return self.port.FixValue(context, value)

    class Diagram:
        def __init__(self, diagram):
            self.diagram = diagram

        def get_input_port(self, i):
            return Port(self.diagram.get_input_port(i))

        def __getattr__(self, name):
            return getattr(self.diagram, name)

    def build(*args, **kwargs):
        scene = real_build(*args, **kwargs)
        scene.diagram = Diagram(scene.diagram)
        return scene

    monkeypatch.setattr(replay, "build_diagram", build)
    task = Task.load("cartpole-wall", ["num_steps=9"])
    t = np.arange(10) * 0.01
    U = np.arange(9, dtype=float)[:, None] + 1.0  # u_k = k + 1
    X = task.dynamics.rollout(task.x0, U)
    replay.write_replay(task, X, t, tmp_path / "r.html", fps=100.0 / 3.0, inputs=U)
    # frames every 0.03 s; each shows the nearest state x_k with its own input u_k
    # (u_8 for the last state, which has none)
    assert [float(u[0]) for u in fixed] == [1.0, 4.0, 7.0, 9.0]


def test_reference_lists_the_torques_that_acted_in_the_plan():
    """A planned command beyond an effort limit acted at the limit in the plan: the exported
    feed-forward (and the PD+ law's ū) hold the limit, not the command."""

    task = Task.load("kinova-forward", ["solver.autodiff_workers=1"], smoke=True)
    dyn = task.dynamics
    lim = dyn.effort_limits
    N = task.steps
    U = task.initial_guess(N)
    U[:, 5] = 3.0 * lim[5]  # beyond the wrist's limit all along
    sol = rollout_plan(task, U)
    r = playback(task, sol, PlaybackSettings(speed=1.0, truth_time_step=0.002))
    assert np.all(np.abs(r.reference.u) <= lim + 1e-12)
    assert np.allclose(r.reference.u[:, 5], lim[5])


def test_the_object_is_the_unactuated_joint_the_plan_moves_most():
    from pathlib import Path

    from pydrake.multibody.tree import JointIndex

    from hydroilqr.control.playback import choose_object

    example = Path(__file__).parents[2] / "examples" / "gripper-brick.yaml"
    task = Task.from_yaml(example, smoke=True)
    dyn, plant = task.dynamics, task.dynamics.plant
    actuated = {
        plant.get_joint_actuator(i).joint().index() for i in plant.GetJointActuatorIndices()
    }
    passive = [
        plant.get_joint(JointIndex(i)) for i in range(plant.num_joints())
        if plant.get_joint(JointIndex(i)).num_positions() == 1 and JointIndex(i) not in actuated
    ]  # fmt: skip
    assert len(passive) >= 2
    last = passive[-1]
    X = np.tile(task.x0, (2, 1))
    X[-1, last.position_start()] += 0.5  # the plan turns/slides the brick about its last joint
    obj = choose_object(dyn, None, X)
    assert obj.coords[0] == last.position_start()
    assert choose_object(dyn).coords[0] == passive[0].position_start()  # no plan: the first


def test_ilqr_policy_refuses_a_plan_saved_without_gains(run_dir):
    task, sol, _ = load_run(run_dir)
    sol.K = np.zeros(0)  # Solution.load accepts such a file (IndexError in the loop before)
    with pytest.raises(ConfigError, match="no feedback gains"):
        playback(task, sol, PlaybackSettings(policy="ilqr", speed=1.0))


def test_naming_the_floating_body_position_is_the_default_choice():
    from hydroilqr.control.playback import choose_object

    dyn = Task.load("kinova-forward", smoke=True).dynamics
    named, default = choose_object(dyn, "ball.position"), choose_object(dyn)
    assert named == default and named.kind == "floating"  # was "joint", without orientation


def test_a_playback_without_replay_removes_the_previous_replay(run_dir, tmp_path):
    from hydroilqr.cli import main

    out = tmp_path / "pb"
    args = ["playback", str(run_dir), "--speed", "1", "--truth-time-step", "0.005"]
    assert main([*args, "--out", str(out)]) == 0 and (out / "playback.html").exists()
    assert main([*args, "--no-replay", "--out", str(out)]) == 0
    assert not (out / "playback.html").exists()  # it showed the earlier playback


def test_a_playback_under_one_truth_step_or_too_long_is_refused(run_dir):
    task, sol, _ = load_run(run_dir)  # plan step 0.01 s, 0.5 s long
    with pytest.raises(ConfigError, match="less than one truth step"):
        playback(task, sol, PlaybackSettings(speed=1e9))  # was: one truth step, exit 0
    with pytest.raises(ConfigError, match="truth steps \\(at most"):
        playback(task, sol, PlaybackSettings(speed=1e-9))  # was: MemoryError
    PlaybackSettings(speed=10.0).check_against(task, 0.5)  # a plan step = one truth step
    # faster: a plan step is shorter than a truth step (as the PD+ reference, held for an
    # update period, always skips plan steps): a coarse playback, but a valid one
    PlaybackSettings(speed=2.0, truth_time_step=0.01).check_against(task, 0.5)
    r = playback(task, sol, PlaybackSettings(policy="ilqr", speed=2.0, truth_time_step=0.01))
    assert len(r.t) == 26  # 0.25 s of playback in 0.01 s steps


def test_pd_loop_options_with_the_ilqr_policy_are_refused_not_ignored(run_dir, tmp_path, capsys):
    from hydroilqr.cli import main

    out = str(tmp_path / "pb")
    rc = main(["playback", str(run_dir), "--policy", "ilqr", "--kp", "100", "--out", out])
    assert rc == 2 and "--kp: options of the PD+ loop" in capsys.readouterr().err
    rc = main(["playback", str(run_dir), "--policy", "ilqr", "--kd", "1", "--rate", "200"])
    assert rc == 2 and "--kd, --rate: options" in capsys.readouterr().err


def test_mismatch_case_plays_as_its_truth_overrides(tmp_path, capsys):
    from hydroilqr.cli import main

    task = Task.load(
        "cartpole-wall",
        ["num_steps=20", "solver.max_iterations=2", "mismatch={soft: {tip.friction: 0.05}}"],
        smoke=True,
    )
    run = tmp_path / "run"
    results.write_solve(task, solve(task), run, replay=False)
    # (no hold after the plan: what is compared is the truth each case builds)
    args = ["playback", str(run), "--policy", "ilqr", "--no-replay", "--rest-max", "0", "--out"]
    assert main([*args, str(tmp_path / "a"), "--mismatch", "soft"]) == 0
    assert main([*args, str(tmp_path / "b"), "--truth-set", "tip.friction=0.05"]) == 0
    a, b = (json.loads((tmp_path / d / "playback.json").read_text()) for d in "ab")
    assert a["truth"]["overrides"] == b["truth"]["overrides"] == ["tip.friction=0.05"]
    assert a["object"]["final_gap"] == b["object"]["final_gap"]
    capsys.readouterr()
    assert main([*args, str(tmp_path / "c"), "--mismatch", "hard"]) == 2
    err = capsys.readouterr().err
    assert "--mismatch hard: cartpole-wall has no such case (it has: soft)" in err
    assert len(err.strip().splitlines()) == 1
    assert main([*args, str(tmp_path / "d"), "--mismatch", "soft", "--mismatch", "soft"]) == 2
    assert "--mismatch soft: given more than once" in capsys.readouterr().err
    # by default a mismatch playback writes beside the nominal one, not over it
    default_out = ["playback", str(run), "--policy", "ilqr", "--no-replay"]
    assert main(default_out) == 0 and main([*default_out, "--mismatch", "soft"]) == 0
    nominal = json.loads((run / "playback-ilqr" / "playback.json").read_text())
    assert nominal["truth"]["overrides"] == []
    changed = json.loads((run / "playback-ilqr-soft" / "playback.json").read_text())
    assert changed["truth"]["overrides"] == ["tip.friction=0.05"]
