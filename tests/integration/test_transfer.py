"""Transfer regression guard (issue 28): each built-in task with an object is solved at full
size, played back open loop (PD+, the paper's gains, half speed) on the "real" simulation,
and the object's resting gap (where it rests against where the plan puts it to rest) and its
distance to the target at rest must not exceed the committed baseline (a ratchet: a gap
that has been reached must stay reached); a lift must keep its fraction of the planned rise.
Tasks with ``mismatch_resting_gap_m`` baselines are also played back with the plan's feedback
policy at full speed on each of the task's ``mismatch:`` cases (the Kinova tasks: the ball's
friction -30 % / +30 %, mass -20 % / +20 %), each resting gap held to its baseline.

Baselines and tolerance: tests/transfer_baseline.json. After a change that makes transfer
better, lower the baseline to the new numbers (``python tests/integration/test_transfer.py`` prints
them); a change that makes it worse by more than the tolerance fails here.

Full-size solves: this module takes minutes, not seconds. HYDROILQR_TRANSFER_SET (dotted
overrides separated by spaces, e.g. ``solver.max_iterations=3``) applies overrides to every
task, to see the guard fail on a deliberately worsened plan.
"""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from hydroilqr import Task
from hydroilqr.control.playback import PlaybackSettings, playback
from hydroilqr.problem.config import mismatch_overrides
from hydroilqr.solver.api import solve

BASELINE = Path(__file__).parents[1] / "transfer_baseline.json"


def _baseline() -> dict:
    return json.loads(BASELINE.read_text())


def measure(name: str) -> dict:
    """Solve the built-in task ``name`` and play it back as the baseline file says."""
    spec = _baseline()
    overrides = os.environ.get("HYDROILQR_TRANSFER_SET", "").split()
    task = Task.load(name, overrides)
    sol = solve(task)
    r = playback(task, sol, PlaybackSettings(**spec["playback"]))
    ob = r.metrics["object"]
    # a lift (kinova-up): the fraction of the planned rise the ball has at the plan's end
    z0, z_plan, z_end = ob["initial"][2], ob["planned_final"][2], ob["actual_final"][2]
    lift = z_plan - z0
    # where the ball rests against the task's target, on the axes its terminal cost weighs (a
    # plan that does not move the ball transfers perfectly, but misses this)
    target = np.asarray(task.config.cost.nominal["ball_position"], float)
    axes = np.broadcast_to(np.asarray(task.config.cost.Qf["ball_position"], float), (3,)) > 0
    miss = (np.asarray(ob["actual_resting"]) - target)[axes]
    # where the plan itself puts the ball to rest (a plan that gives up on the push transfers
    # perfectly and may even rest nearer the target than a bad transfer: this catches it)
    planned_miss = (np.asarray(ob["planned_resting"]) - target)[axes]
    return {
        "resting_gap_m": ob["resting_gap"],
        "resting_target_error_m": float(np.linalg.norm(miss)),
        "planned_resting_target_error_m": float(np.linalg.norm(planned_miss)),
        "final_gap_m": ob["final_gap"],
        "kept_lift_fraction": float((z_end - z0) / lift) if abs(lift) > 0.02 else None,
        "rested": ob["rest"]["actual"]["rested"],
        "warnings": r.metrics["warnings"],
        **_mismatch(task, sol, spec, name),
    }


def _mismatch(task, sol, spec: dict, name: str) -> dict:
    """Resting gap per mismatch case of the task, for a task whose baseline has them."""
    if "mismatch_resting_gap_m" not in spec["tasks"][name]:
        return {}
    mm, gaps = spec["mismatch"], {}
    for case in task.config.mismatch:
        truth = mismatch_overrides(task.config, case)
        st = PlaybackSettings(policy=mm["policy"], speed=mm["speed"], truth_overrides=truth)
        gaps[case] = playback(task, sol, st).metrics["object"]["resting_gap"]
    return {"mismatch_resting_gap_m": gaps}


@pytest.mark.parametrize("name", sorted(_baseline()["tasks"]))
def test_transfer_does_not_regress(name):
    spec = _baseline()
    want = spec["tasks"][name]
    rel, floor = spec["tolerance"]["relative"], spec["tolerance"]["absolute_m"]
    got = measure(name)
    limit = want["resting_gap_m"] * (1 + rel) + floor
    assert got["resting_gap_m"] <= limit, (
        f"{name}: resting gap {got['resting_gap_m']:.4f} m > baseline "
        f"{want['resting_gap_m']:.4f} m (+{100 * rel:g} % +{floor:g} m = {limit:.4f} m)"
    )
    limit = want["resting_target_error_m"] * (1 + rel) + floor
    assert got["resting_target_error_m"] <= limit, (
        f"{name}: the ball rests {got['resting_target_error_m']:.4f} m from its target > "
        f"baseline {want['resting_target_error_m']:.4f} m (limit {limit:.4f} m)"
    )
    if want.get("planned_resting_target_error_m") is not None:
        limit = want["planned_resting_target_error_m"] * (1 + rel) + floor
        assert got["planned_resting_target_error_m"] <= limit, (
            f"{name}: the plan rests the ball {got['planned_resting_target_error_m']:.4f} m from "
            f"its target > baseline {want['planned_resting_target_error_m']:.4f} m "
            f"(limit {limit:.4f} m)"
        )
    for case, gap in want.get("mismatch_resting_gap_m", {}).items():
        limit = gap * (1 + rel) + floor
        assert case in got["mismatch_resting_gap_m"], f"{name}: no mismatch case {case!r}"
        got_gap = got["mismatch_resting_gap_m"][case]
        assert got_gap <= limit, (
            f"{name}, {case} (--policy {spec['mismatch']['policy']}): resting gap "
            f"{got_gap:.4f} m > baseline {gap:.4f} m (limit {limit:.4f} m)"
        )
    if want.get("kept_lift_fraction") is not None:
        keep = want["kept_lift_fraction"] - spec["tolerance"]["lift_fraction"]
        assert got["kept_lift_fraction"] is not None and got["kept_lift_fraction"] >= keep, (
            f"{name}: kept {got['kept_lift_fraction']} of the planned lift < {keep:.3f}"
        )


if __name__ == "__main__":  # print today's numbers, to lower the baseline after an improvement
    print(json.dumps({name: measure(name) for name in sorted(_baseline()["tasks"])}, indent=2))
