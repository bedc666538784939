"""`hydroilqr check`: what it reports about a task file before any solve."""

from __future__ import annotations

import pytest
import yaml

from hydroilqr import Task, cli
from tests.conftest import assert_one_line, edit, write_case


def test_check_warns_that_a_rigid_geometrys_modulus_is_unused():
    from hydroilqr.studies.check import check_task

    task = Task.load(
        "cartpole-wall",
        ["geometry.tip.compliance=rigid", "geometry.tip.resolution_hint=0.01"],
        smoke=True,
    )
    out = check_task(task)
    assert any("hydroelastic_modulus is not used" in w for w in out["warnings"])


def test_check_validates_the_smoke_section(tmp_path, capsys):
    path = write_case(tmp_path, edit(smoke={"solver.max_iterations": -1}))
    rc = cli.main(["check", str(path)])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "solver.max_iterations")


def test_check_names_a_deep_initial_overlap_even_when_the_rollout_survives(capsys):
    deep = "initial_state.ball_position=[0.4, 0, 0.06]"  # 4 cm into the floor
    rc = cli.main(["check", "kinova-forward", "--set", deep])
    out = capsys.readouterr().out
    assert rc == 0 and "ball_collision (ball) and ground (world) overlap by 40 mm" in out
    assert cli.main(["check", "kinova-forward"]) == 0  # resting 1.6 mm deep: no warning
    assert "overlap by" not in capsys.readouterr().out


def test_check_lists_the_ensemble_members_and_rolls_the_guess_on_each(tmp_path, capsys):
    from tests.conftest import write_task

    member = {"plant.gravity": [0, 0, -8]}
    task = write_task(tmp_path, num_steps=5, ensemble=[member], ensemble_weight=0.5)
    assert cli.main(["check", str(task)]) == 0
    out = capsys.readouterr().out
    assert "ensemble[0] (weight 0.5, guess rollout ok): plant.gravity=[0, 0, -8]" in out
    assert "check passed" in out


STRIKE_URDF = """<?xml version="1.0"?>
<robot name="pend">
  <link name="base"/>
  <link name="rod">
    <inertial><origin xyz="0 0 -0.25"/><mass value="0.5"/>
      <inertia ixx="0.01" iyy="0.01" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision name="rod_collision"><origin xyz="0 0 -0.25"/>
      <geometry><box size="0.02 0.02 0.5"/></geometry></collision>
  </link>
  <joint name="theta" type="revolute">
    <parent link="base"/><child link="rod"/><origin xyz="0 0 0.6"/><axis xyz="0 1 0"/>
    <limit effort="10" velocity="100" lower="-10" upper="10"/>
  </joint>
  <transmission type="SimpleTransmission" name="t">
    <actuator name="theta_motor"/><joint name="theta"/>
    <mechanicalReduction>1</mechanicalReduction>
  </transmission>
  <link name="cube">
    <inertial><mass value="0.2"/>
      <inertia ixx="0.0003" iyy="0.0003" izz="0.0003" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision name="cube_collision"><geometry><box size="0.1 0.1 0.1"/></geometry></collision>
  </link>
</robot>
"""


def strike_task(tmp_path, steps: int = 120):
    """A pendulum hanging still 1 cm beside a cube on a table that the cost wants moved."""
    (tmp_path / "pend.urdf").write_text(STRIKE_URDF)
    return write_case(
        tmp_path,
        {
            "name": "strike",
            "models": [{"file": "pend.urdf", "weld": {"parent": "world", "child": "base"}}],
            "scene": [
                {"name": "table", "shape": "box", "size": [2, 2, 0.1], "xyz": [0, 0, -0.05],
                 "compliance": "compliant", "hydroelastic_modulus": 1.0e6}
            ],
            "plant": {"time_step": 0.01},
            "num_steps": steps,
            "initial_state": {"theta": 0.0, "cube.position": [0.07, 0, 0.05]},
            "cost": {"Q": {"cube.position": 1.0}, "Qf": {"cube.position": 100.0}, "R": 0.01,
                     "nominal": {"cube.position": [0.5, 0, 0.05]}},
            "solver": {"max_iterations": 2},
        },
    )  # fmt: skip


def test_check_and_solve_agree_on_no_contact_and_its_remedy(tmp_path, capsys):
    """Issue 39, 1: a cube resting on the table, 1 cm from a still pendulum. check judges the
    whole guess (not only its first 50 steps) by solve's test (contact with something that
    moves), warns, and gives solve's remedy: an approach term or a guess that moves, not a
    closer start."""
    remedy = "add an approach term (a distance term in cost.terms between the robot's geometry"
    path = strike_task(tmp_path)
    assert cli.main(["check", str(path)]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "over the first 50 of the task's 120 steps" in out
    assert "along the rollout of the initial guess (120 steps)" in out
    assert "cube touches only what is fixed to the world" in out and remedy in out
    assert "a closer start alone does not help" in out
    assert "check passed with 1 warning(s)" in out
    run = ["solve", str(path), "--out", str(tmp_path / "o"), "--no-replay"]
    assert cli.main(run) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "status no_progress after 1 iteration (stop test: expected_decrease)" in out
    assert remedy in out and "a closer start alone does not help" in out


def test_a_negative_mass_in_a_model_is_refused_in_one_line(tmp_path, capsys):
    """Issue 39: Drake parses a negative mass with a warning and a made-up inertia; the task
    is refused instead, naming the file and line."""
    path = strike_task(tmp_path)
    urdf = tmp_path / "pend.urdf"
    urdf.write_text(STRIKE_URDF.replace('<mass value="0.2"/>', '<mass value="-0.2"/>'))
    rc = cli.main(["check", str(path)])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "models[0].file: pend.urdf line ")
    assert "a mass or inertia no physical body has" in cap.err


@pytest.mark.parametrize("case", ["dev-zero-mesh", "fifo-mesh", "fifo-include"])
def test_model_files_name_only_regular_bounded_files(tmp_path, capsys, case):
    """Issue 39: a mesh (visual or collision) that is /dev/zero or a named pipe, or an
    <include> of a pipe, is refused in one line before Drake reads it (it exhausted memory
    or waited forever)."""
    import os
    import signal

    path = strike_task(tmp_path)
    os.mkfifo(tmp_path / "pipe.obj")
    mesh = {"dev-zero-mesh": "/dev/zero", "fifo-mesh": "pipe.obj"}.get(case)
    if mesh:
        visual = f'<visual><geometry><mesh filename="{mesh}"/></geometry></visual>'
        text = STRIKE_URDF.replace('<collision name="cube_collision">', visual + "<collision>")
        (tmp_path / "pend.urdf").write_text(text)
    else:
        (tmp_path / "holder.sdf").write_text(
            '<?xml version="1.0"?><sdf version="1.9"><model name="holder"><link name="l"/>'
            "<include><uri>pipe.obj</uri></include></model></sdf>"
        )
        path.write_text(path.read_text().replace("models:\n", "models:\n- file: holder.sdf\n"))

    def hung(*_):
        raise TimeoutError("the model check waited on a file")

    old = signal.signal(signal.SIGALRM, hung)
    signal.alarm(60)
    try:
        rc = cli.main(["check", str(path)])
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    cap = capsys.readouterr()
    kind = "a character device" if case == "dev-zero-mesh" else "a named pipe"
    assert_one_line(rc, cap.out, cap.err, f"{kind}, not a regular file")


@pytest.mark.parametrize(
    "section, needle",
    [
        ({"rate": 33}, "33 Hz"),
        ({"truth_overrides": ["nosuchbody.friction=0.3"]}, "mpc.truth_overrides"),
        ({"plan_overrides": ["plant.time_step=0.02"]}, "mpc.plan_overrides"),
    ],
)
def test_check_refuses_an_mpc_section_that_mpc_would_refuse(tmp_path, capsys, section, needle):
    path = tmp_path / "task.yaml"
    path.write_text(yaml.safe_dump({"extends": "cartpole-wall", "mpc": section}))
    rc = cli.main(["check", str(path)])
    cap = capsys.readouterr()
    assert rc == 2 and needle in cap.err and "Traceback" not in cap.err


def test_check_does_not_read_an_mpc_warm_start_plan_that_a_later_solve_writes(tmp_path, capsys):
    path = tmp_path / "task.yaml"
    section = {"warm_start_plan": "run"}  # (relative to the task file: not solved yet)
    path.write_text(yaml.safe_dump({"extends": "cartpole-wall", "mpc": section}))
    assert cli.main(["check", str(path)]) == 0


def test_check_replay_writes_the_guess_rollout(tmp_path, capsys):
    """`check --replay FILE.html` shows the initial guess without a solve (issue 54, item 10):
    the replay of the guess's rollout over the whole horizon; a bad path is one line, exit 2,
    before any work."""
    from hydroilqr.studies.check import guess_trajectory

    path = write_case(tmp_path, edit(initial_guess="gravity_compensation"))
    out = tmp_path / "guess.html"
    assert cli.main(["check", str(path), "--replay", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    assert out.stat().st_size > 10_000 and "meshcat" in out.read_text().lower()
    t, X, U = guess_trajectory(Task.from_yaml(path))
    assert len(t) == len(X) == len(U) + 1 == 6 and t[-1] == pytest.approx(0.1)
    rc = cli.main(["check", str(path), "--replay", str(tmp_path / "no" / "guess.html")])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "--replay")


def test_a_solve_of_zero_iterations_says_the_plan_is_the_guess(tmp_path, capsys):
    path = write_case(tmp_path, edit())
    cli.main(["solve", "--task-file", str(path), "--max-iterations", "0", "--no-replay",
              "--out", str(tmp_path / "run")])  # fmt: skip
    out = capsys.readouterr().out
    assert "the plan is the initial guess itself" in out and "local minimum" not in out


def test_check_tables_keep_every_column_at_80_columns_and_pipes_keep_sentences_whole(
    capsys, monkeypatch
):
    """Issue 54, item 12: a table wider than the terminal becomes one line per row (rich
    squeezed the pairs table's kinds / model / distance columns to nothing at 80 columns);
    piped, a warning is one line however long (it wrapped near 160 characters)."""
    import subprocess
    import sys

    from hydroilqr.cli.common import console

    monkeypatch.setattr(console, "width", 80)
    assert cli.main(["check", "kinova-forward"]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("  bracelet_link_collision ("))
    assert "/ ball_collision (ball): kinds rigid/compliant, contact model hydroelastic" in line
    assert "distance at x0 [m] 0.0" in line
    monkeypatch.undo()
    piped = subprocess.run(
        [sys.executable, "-m", "hydroilqr", "check", "kinova-forward", "--set", "cost.R=0"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    (warning,) = [ln for ln in piped.splitlines() if ln.startswith("warning:")]
    assert len(warning) > 160 and warning.rstrip().endswith('"From no contact to contact")')
