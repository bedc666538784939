"""Transfer guard: properties of the Kinova plans that must hold in whichever local minimum the
solver lands in.

Contact-rich solves land in different basins for last-bit differences (another CPU's BLAS
kernels are enough), so a guard that holds one basin's numbers fails on another machine
without anything having regressed. This guard instead solves each Kinova task twice from its
initial guess perturbed by a relative 1e-9 (``studies.robustness``, runs 1 and 2 of seed 0),
plays each plan back the way the paper ran it on hardware (PD+ at the paper's gains, half
speed, on the finer simulation with the other contact approximation) and asserts:

- the plan meets the task's goal (the solve did its job);
- a push (kinova-forward, kinova-left): the ball rests within ``MAX_RESTING_GAP_M`` of where
  the plan, extended the same way, puts it to rest: the length of kinova-forward's push, so a
  playback that loses the push (the ball left behind, or rolling away) fails, while the
  centimetres by which different basins' plans transfer differently do not.

The push bound is loose on purpose: kinova-forward's plans brake the ball by squeezing it
into the compliant floor. The planning model's own extension past the plan lets the squeezed
ball spring out and roll on, so the resting gap measures mostly that; the played-back ball
(SAP, half speed) stops a few centimetres short of the target, so its goal on the executed
motion is missed while the push itself is kept (``hydroilqr robustness kinova-forward
--transfer`` measures both: ``transfer.values`` is the executed target error).

Measured and reported by ``measure`` but not asserted, because they hold in some basins and
not in others (run under other BLAS kernel sets): the task's goal judged on the executed
motion (a plan that ends the ball near the edge of its 3 cm goal misses it after a transfer
error of a centimetre or two), kinova-up's lift under PD+ at half speed (some basins' lifts
drop the ball), and kinova-left's resting gap under its ``mismatch:`` cases. Asserting them
would again encode one basin; making them hold in every basin is open work.
kinova-forward's default plan brakes the ball by pressing it into the floor and does not
survive 30 % less friction; its robust variant is examples/kinova-forward-robust.yaml.

A real regression fails it: ``HYDROILQR_TRANSFER_SET="solver.max_iterations=3"`` (dotted
overrides separated by spaces, applied to every task) gives plans that miss their goals.
``python tests/integration/test_transfer.py TASK RUNS`` measures the same properties over
runs 1..RUNS on Dask and prints them, with the executed goal's values under playbacks that
change one thing at a time (``PARTS``: full speed; full speed at the plan's own time step;
full speed under the planner's own contact model), which say where a plan and its playback
part.

Full-size solves: this module takes minutes, not seconds.
"""

import json
import os
import sys

import numpy as np
import pytest

from hydroilqr import Task
from hydroilqr.control.playback import HALF_SPEED, PlaybackSettings, executed_goal, playback
from hydroilqr.metrics import compute
from hydroilqr.metrics.goals import evaluate
from hydroilqr.problem.variants import mismatch_overrides
from hydroilqr.solver.api import solve
from hydroilqr.studies.multistart import perturbation
from hydroilqr.studies.robustness import DEFAULT_NOISE

# The longest first (the slow tests run first, two at a time: see tests/conftest.py).
TASKS = ("kinova-up", "kinova-forward", "kinova-left")
RUNS = (1, 2)  # perturbed solves per task
MAX_RESTING_GAP_M = 0.2  # pushes: the length of kinova-forward's push
PUSHES = ("kinova-forward", "kinova-left")
HALF_SPEED_PD = PlaybackSettings(**HALF_SPEED)  # the paper's hardware playback


# Each solve computes in its own process: the test runner (and the study's Dask cluster)
# already runs one job per core, and a solve's own worker processes on top of that only compete
# for the same cores. The iterates are bitwise those of the parallel solve.
SERIAL = ["solver.autodiff_workers=1", "solver.line_search_workers=1"]


def _overrides() -> list[str]:
    return SERIAL + os.environ.get("HYDROILQR_TRANSFER_SET", "").split()


# Where a plan and its playback part (docs/playback.md, "What decides transfer"): the same plan
# played with one thing of the hardware-style playback changed at a time.
PARTS = {
    "full_speed": {"speed": 1.0},
    "full_speed_plan_step": {"speed": 1.0, "truth_time_step": None},  # None: the plan's step
    "full_speed_planner_contact": {"speed": 1.0, "truth_contact": None},  # None: the planner's
}


def parts(task, sol) -> dict:
    """The executed goal's values of the plan ``sol`` under each playback of ``PARTS``."""
    out = {}
    for label, changes in PARTS.items():
        st = dict(changes)
        if "truth_time_step" in st:
            st["truth_time_step"] = task.config.plant.time_step
        if "truth_contact" in st:
            st["truth_contact"] = task.config.plant.contact_approximation
        r = playback(task, sol, PlaybackSettings(**st))
        checks = executed_goal(task, sol, r)["goal"]["checks"]
        out[label] = {c["metric"]: c["value"] for c in checks}
    return out


def measure(
    name: str, k: int, mismatch: bool | None = None, play: bool = True, split: bool = False
) -> dict:
    """Solve the built-in task ``name`` from run ``k``'s perturbed guess, play it back and
    return every property the guard asserts (``mismatch``: also play the task's mismatch
    cases; default: for the tasks the guard holds to them; ``play=False``: the plan's goal
    only, no playback; ``split``: also the executed goal's values under ``PARTS``)."""
    task = Task.load(name, _overrides())
    U0 = task.initial_guess(task.config.steps)
    sol = solve(task, U0=perturbation(U0, task.dynamics.effort_limits, DEFAULT_NOISE, 0, k))
    plan_goal = evaluate(task.config.goal, compute(task, sol))
    if not play:
        return {
            "task": name,
            "run": k,
            "plan_goal_met": plan_goal["met"],
            "plan_failed_checks": [c["metric"] for c in plan_goal["checks"] if not c["passed"]],
        }
    r = playback(task, sol, HALF_SPEED_PD)
    executed = executed_goal(task, sol, r)["goal"]
    ob = r.metrics["object"]
    z0, z_plan, z_end = ob["initial"][2], ob["planned_final"][2], ob["actual_final"][2]
    lift = z_plan - z0
    out = {
        "task": name,
        "run": k,
        "plan_goal_met": plan_goal["met"],
        "plan_failed_checks": [c["metric"] for c in plan_goal["checks"] if not c["passed"]],
        "executed_goal_met": executed["met"],
        "executed_values": {c["metric"]: c["value"] for c in executed["checks"]},
        "resting_gap_m": ob["resting_gap"],
        "kept_lift_fraction": float((z_end - z0) / lift) if abs(lift) > 0.02 else None,
        "mismatch": {},
        **({"executed_by_playback": parts(task, sol)} if split else {}),
    }
    if mismatch is None:
        mismatch = False  # (reported by the study, not asserted: see the module's docstring)
    for case in task.config.mismatch if mismatch else ():
        truth = mismatch_overrides(task.config, case)
        st = PlaybackSettings(policy="ilqr", speed=1.0, truth_overrides=truth)
        pb = playback(task, sol, st)
        out["mismatch"][case] = {
            "executed_goal_met": executed_goal(task, sol, pb)["goal"]["met"],
            "resting_gap_m": pb.metrics["object"]["resting_gap"],
        }
    return out


def problems(m: dict) -> list[str]:
    """What the guard finds wrong with one measurement (empty: it passes)."""
    name, k = m["task"], m["run"]
    where = f"{name} run {k}"
    found = []
    if not m["plan_goal_met"]:
        found.append(f"{where}: the plan misses its goal ({', '.join(m['plan_failed_checks'])})")
    if name in PUSHES and (m["resting_gap_m"] is None or m["resting_gap_m"] > MAX_RESTING_GAP_M):
        found.append(
            f"{where}: the ball rests {m['resting_gap_m']} m from where the plan puts it "
            f"(> {MAX_RESTING_GAP_M} m)"
        )
    return found


@pytest.mark.slow
@pytest.mark.parametrize("name", TASKS)
@pytest.mark.parametrize("k", RUNS)
def test_transfer_holds_in_any_basin(name, k):
    # (a lift's playback is measured by the study, not asserted: see the module's docstring)
    found = problems(measure(name, k, play=name in PUSHES))
    assert not found, "; ".join(found)


def _study(name: str, runs: int) -> None:
    """Measures runs 1..``runs`` of ``name`` as Dask jobs; prints one JSON line per run and
    how many runs the guard passes."""
    from distributed import as_completed

    from hydroilqr.studies.cluster import open_client

    client, cluster = open_client(None, None)
    try:
        futs = [
            client.submit(measure, name, k, True, True, True, pure=False)
            for k in range(1, runs + 1)
        ]
        passed = 0
        for f in as_completed(futs):
            m = f.result()
            found = problems(m)
            passed += not found
            print(json.dumps({**m, "problems": found}, default=float), flush=True)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    print(f"{name}: the guard passes {passed} of {runs} perturbed solves")


if __name__ == "__main__":
    np.seterr(all="ignore")
    _study(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 10)
