"""Every bad key gives a one-line error naming it, before any solve starts (issue 9).

Each case writes a task file next to nothing but itself (the model is Drake's acrobot or
pendulum, shipped in the drake wheel), runs ``hydroilqr solve`` on it and checks: non-zero exit,
exactly one line on stderr, no traceback, the offending key in the message, nothing printed on
stdout (so the solve never started). All cases run in-process through ``cli.main``; a subset
also runs as real subprocesses of the installed ``hydroilqr`` script.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from hydroilqr import cli
from tests.conftest import ACROBOT, BASE, assert_one_line, edit, write_case

PENDULUM = "package://drake/examples/pendulum/Pendulum.urdf"


HYDROILQR = Path(sys.executable).parent / "hydroilqr"


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
    ("ensemble-time-step", edit(ensemble=[{"plant.time_step": 0.01}]), "ensemble[0]: plant"),
    (
        "ensemble-time-step-nested",
        edit(ensemble=[{"plant": {"time_step": 0.01}}]),
        "ensemble[0]: the time grid",
    ),
    ("ensemble-unknown-key", edit(ensemble=[{"tipp.friction": 0.1}]), "ensemble[0]"),
    ("ensemble-solver", edit(ensemble=[{"solver.max_iterations": 2}]), "ensemble[0]: solver"),
    ("ensemble-not-a-mapping", edit(ensemble=[0.3]), "ensemble[0]: expected a mapping"),
    ("ensemble-weight", edit(ensemble_weight=-1), "ensemble_weight: must be >= 0"),
    (
        "ensemble-receding",
        edit(
            ensemble=[{"plant.gravity": [0, 0, -9]}],
            receding_horizon={"window_steps": 2, "shift_steps": 1, "resolves": 1},
        ),
        "ensemble: for single solves",
    ),
    (
        "ensemble-continuation",
        edit(ensemble=[{"plant.gravity": [0, 0, -9]}], continuation=[{"plant.gravity": [0, 0, 1]}]),
        "ensemble: not supported together with continuation",
    ),
    ("mismatch-not-a-mapping", edit(mismatch={"lighter": 0.8}), "mismatch.lighter: expected"),
    ("mismatch-bad-name", edit(mismatch={"a b": {"tip.friction": 0.1}}), "mismatch: 'a b'"),
    ("mismatch-solver", edit(mismatch={"x": {"solver.max_iterations": 2}}), "mismatch.x: solver"),
    ("mismatch-unknown-body", edit(mismatch={"x": {"tipp.friction": 0.1}}), "mismatch.x: geom"),
    (
        "mismatch-time-step",
        edit(mismatch={"x": {"plant.time_step": 0.001}}),
        "mismatch.x: plant.time_step: playback sets it with --truth-time-step",
    ),
    (
        "mismatch-nested-contact",
        edit(mismatch={"x": {"plant": {"contact_approximation": "sap"}}}),
        "mismatch.x: plant.contact_approximation: playback sets it with --truth-contact",
    ),
]


SUBPROCESS_CASES = [
    "unknown-top-level-key",
    "nan-weight",
    "malformed-yaml",
    "compliant-halfspace-pair",
]


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


def _nested(depth: int, block: bool) -> str:
    if block:  # a block mapping, one level per line
        return "metric_params:\n" + "".join("  " * (i + 1) + f"k{i}:\n" for i in range(depth))
    return "metric_params: {x: " + "[" * depth + "]" * depth + "}\n"


@pytest.mark.parametrize("depth, block", [(40, False), (40, True), (5000, False)])
def test_nesting_a_task_cannot_mean_is_one_line(tmp_path, capsys, depth, block):
    """Issue 39: deeply nested YAML (sequences, flow or block mappings) is refused in one
    line, naming the key when the YAML could be read (not an internal error)."""
    import yaml

    text = yaml.safe_dump(BASE) + _nested(depth, block)
    rc = cli.main(["solve", str(write_case(tmp_path, text)), "--out", str(tmp_path / "o")])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "nested more than 32 levels deep")
    if depth < 100:
        assert "metric_params: nested" in cap.err


def test_values_that_are_no_yaml_data_are_refused_naming_the_key():
    """From Python: a complex number (or another object) where any data is allowed."""
    from hydroilqr.problem.errors import ConfigError
    from hydroilqr.problem.load import task_from_dict

    for section, value, where in (
        ("metric_params", {"x": 1 + 2j}, "metric_params.x"),
        ("smoke", {"num_steps": [1j]}, "smoke.num_steps[0]"),
        ("metric_params", {"x": object()}, "metric_params.x"),
    ):
        with pytest.raises(ConfigError, match=rf"^{re.escape(where)}: expected YAML data"):
            task_from_dict({**BASE, section: value})


def test_a_bad_value_the_smoke_section_overrides_is_still_refused(tmp_path, capsys):
    """Issue 39: solver.max_iterations 1.5 is refused with --smoke too (the smoke section
    replacing it hid it)."""
    path = write_case(
        tmp_path, edit(solver__max_iterations=1.5, smoke={"solver.max_iterations": 1})
    )
    for extra in ([], ["--smoke"]):
        rc = cli.main(["solve", str(path), "--out", str(tmp_path / "o"), *extra])
        cap = capsys.readouterr()
        assert_one_line(rc, cap.out, cap.err, "solver.max_iterations: expected an integer")


@pytest.mark.parametrize(
    "change, key",
    [
        ({"cost__nominal": {"angles": 1e200}}, "cost.nominal.angles"),
        ({"cost__Q": {"angles": 1e300}}, "cost.Q.angles"),
        ({"cost__R": [1e200]}, "cost.R"),
    ],
)
def test_numbers_too_large_for_the_cost_are_one_line(tmp_path, capsys, change, key):
    """Issue 39: a huge nominal printed overflow warnings and more lines; now one line."""
    path = write_case(tmp_path, edit(**change))
    rc = cli.main(["solve", str(path), "--out", str(tmp_path / "o")])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, f"{key}: ")
    assert "too large to compute a cost with" in cap.err


@pytest.mark.parametrize(
    "text, needle",
    [
        ("extends: cartpole-wall\n? [a, b]\n: c\n", "line 2: a key that is a list or a mapping"),
        ("extends: cartpole-wall\nmetric_params:\n  ? {a: 1}\n  : c\n", "line 3: a key that is"),
        ("extends: cartpole-wall\nhorizon: 1\0\0\n", "line 2: unacceptable character #x0000"),
    ],
)
def test_yaml_a_task_file_cannot_hold_is_one_line(tmp_path, capsys, text, needle):
    """Issue 53, 4-5: a complex key was an internal TypeError; a NUL byte a two-line
    error."""
    path = tmp_path / "task.yaml"
    path.write_text(text)
    rc = cli.main(["check", str(path)])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, needle)


@pytest.mark.parametrize(
    "guess, needle",
    [
        ("{waypoints: [{t: 0.5, pole_angle: left}]}", "initial_guess.waypoints[0].pole_angle"),
        ("{waypoints: [{t: 0.5, pole_angle: {a: 1}}]}", "waypoints[0].pole_angle: expected a"),
        ("{waypoints: [{t: 0.5, pole_angle: [[1, 2], [3]]}]}", "[0].pole_angle: expected a"),
        ("{target: {pole_angle: .inf}}", "initial_guess.target.pole_angle"),
        ("{waypoints: [{t: 0.5, pole_angle: 1}], period: .nan}", "initial_guess.period"),
        ("{waypoints: [{t: 0.5, pole_angle: 1}], period: [1]}", "initial_guess.period"),
        ("{waypoints: 3}", "initial_guess.waypoints: expected a list"),
    ],
)
def test_a_bad_waypoint_or_mapping_of_a_guess_is_named_by_its_key(tmp_path, capsys, guess, needle):
    """Issue 53, 8: waypoint values were internal errors; a bad mapping was "expected a
    string" (the other form initial_guess takes)."""
    path = tmp_path / "task.yaml"
    path.write_text(f"extends: cartpole-wall\ninitial_guess: {guess}\n")
    rc = cli.main(["check", str(path)])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, needle)
    assert "expected a string" not in cap.err
