"""What a playback measured: the object's planned against actual motion (at the plan's end
and at rest), joint tracking, torques; the executed motion's task metrics and goal
(``control/playback.py`` computes them; re-exported there)."""

from __future__ import annotations

from dataclasses import asdict
from types import SimpleNamespace

import numpy as np

from hydroilqr import metrics
from hydroilqr.control.playback_settings import PlaybackResult, damping_law
from hydroilqr.metrics.goals import judge
from hydroilqr.model.plant import SimulationError
from hydroilqr.model.scene import left_scene, scene_box
from hydroilqr.model.state import quat_conj, quat_mul


def _angle_between(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """Rotation angle (rad) between quaternions (wxyz). [..., 4] -> [...]."""
    e = quat_mul(quat_conj(qb), qa)
    return 2.0 * np.arctan2(np.linalg.norm(e[..., 1:], axis=-1), np.abs(e[..., 0]))


def _rest_caveat(task, r: PlaybackResult) -> tuple[str, bool]:
    """Why the resting gap would measure an artefact, and whether to drop it: ('', False)
    when both sides rest in the scene; (why, True) when the planning model's extension or
    the playback carried a floating object out of the scene (a joint object has no scene to
    leave); (why, False) when the extension did not come to rest (the gap is kept as data,
    against where the extension was at --rest-max, but is no headline)."""
    h, ob = r.hold, r.metrics["object"]
    if h is None or ob.get("resting_gap") is None:
        return "", False
    where = ""
    if r.obj.kind == "floating":
        box = scene_box(task, r.X[0])
        for side, key in (("the planning model's extension", "planned_resting"),
                          ("the playback", "actual_resting")):  # fmt: skip
            p = np.asarray(ob[key], float)
            if left_scene(box, p):
                where = f"{side} carried the object out of the scene (to {_xyz(p)} m)"
                break
    if where:
        return f"{where}; the plan's end is the measure (final gap)", True
    if not h.rested_plan:
        return (
            f"the planning model's extension did not come to rest within "
            f"{r.settings.rest_max:g} s (--rest-max), so the resting gap compares with where "
            "it was then; the plan's end is the measure (final gap)",
            False,
        )
    return "", False


def _xyz(p: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.3g}" for v in p) + "]"


def _gap_key(name: str, unit: str) -> str:
    """``resting_gap_m`` for an object measured in metres (``_rad`` in radians)."""
    return f"{name}_{unit}" if unit else name


def _metrics(r: PlaybackResult, qi, vi, limits, vscale, saturated, controls, x_plan_final) -> dict:
    o = r.obj
    c = list(o.coords)
    e = len(r.t) - 1
    actual, planned = r.X[:, c], r.X_plan[:, c]
    err = np.linalg.norm(actual - planned, axis=1)
    kmax = int(np.argmax(err))
    planned_final, actual_final = x_plan_final[c], r.X[e, c]
    planned_disp = planned_final - r.X[0, c]
    actual_disp = actual_final - r.X[0, c]
    pd2 = float(planned_disp @ planned_disp)
    obj = {
        "name": o.name,
        "kind": o.kind,
        "unit": o.unit,
        "initial": r.X[0, c],
        "planned_final": planned_final,
        "actual_final": actual_final,
        "final_error": actual_final - planned_final,
        "final_gap": float(np.linalg.norm(actual_final - planned_final)),
        "max_deviation": float(err[kmax]),
        "max_deviation_time_s": float(r.t[kmax]),
        "planned_displacement": float(np.sqrt(pd2)),
        "actual_displacement": float(np.linalg.norm(actual_disp)),
        # Fraction of the planned displacement achieved along its direction.
        "progress_ratio": float(actual_disp @ planned_disp / pd2) if pd2 > 1e-12 else None,
    }
    h = r.hold
    if h is not None:
        # Where the object came to rest (the robot holding its last reference), against where
        # the planning model, extended the same way, puts it to rest.
        planned_rest = h.X_settle[-1, c]
        actual_rest = h.X[-1, c] if len(h.X) else r.X[-1, c]
        rest_disp = actual_rest - r.X[0, c]
        obj.update(
            {
                "planned_resting": planned_rest,
                "actual_resting": actual_rest,
                "resting_error": actual_rest - planned_rest,
                "resting_gap": float(np.linalg.norm(actual_rest - planned_rest)),
                "planned_rest_drift": float(np.linalg.norm(planned_rest - planned_final)),
                "resting_progress_ratio": (
                    float(rest_disp @ planned_disp / pd2) if pd2 > 1e-12 else None
                ),
                "rest": h.summary(),
            }
        )
    if o.orientation:
        oc = list(o.orientation)
        ang = _angle_between(r.X[:, oc], r.X_plan[:, oc])
        obj["final_orientation_error_deg"] = float(
            np.degrees(_angle_between(r.X[e, oc], x_plan_final[oc]))
        )
        obj["max_orientation_deviation_deg"] = float(np.degrees(ang.max()))
    q_err = r.X[: e + 1, qi] - r.X_plan[: e + 1, qi]  # tracking: while the plan runs
    v_err = r.X[: e + 1, vi] - vscale * r.X_plan[: e + 1, vi]
    joints = {
        name: {
            "unit": unit,
            "rms_error": float(np.sqrt(np.mean(q_err[:, i] ** 2))),
            "max_abs_error": float(np.max(np.abs(q_err[:, i]))),
            "rms_velocity_error": float(np.sqrt(np.mean(v_err[:, i] ** 2))),
            "final_error": float(q_err[-1, i]),
        }
        for i, (name, unit) in enumerate(zip(r.joints, r.joint_units))
    }
    torques = {
        name: {
            "max_abs": float(np.max(np.abs(r.U[:, i]))) if len(r.U) else 0.0,
            "effort_limit": float(limits[i]) if np.isfinite(limits[i]) else None,
        }
        for i, name in enumerate(r.actuators)
    }
    st = r.settings
    return {
        "policy": st.policy,
        "settings": asdict(st),
        "truth": {
            "time_step": st.truth_time_step,
            "contact_approximation": r.truth_contact,
            "damping": damping_law(r.truth_contact),
            "overrides": list(st.truth_overrides),
        },
        "planner": {
            "time_step": r.planner_time_step,
            "contact_approximation": r.planner_contact,
            "damping": damping_law(r.planner_contact),
        },
        "plan_duration_s": float(r.t[e] * st.speed),
        "playback_duration_s": float(r.t[e]),
        "hold_duration_s": h.seconds if h is not None else 0.0,
        "truth_steps": int(len(r.U)),
        "hold_truth_steps": int(len(h.U)) if h is not None else 0,
        # the headline: where the object rests against where the plan puts it to rest (None
        # without a resting measurement, rest_max 0); final_gap: at the plan's last instant
        _gap_key("resting_gap", o.unit): obj.get("resting_gap"),
        _gap_key("final_gap", o.unit): obj["final_gap"],
        "control_updates": int(controls),
        "reference_updates": int(len(r.reference.t)),
        "object": obj,
        "joint_tracking": joints,
        "joint_rms_error_max": max((j["rms_error"] for j in joints.values()), default=0.0),
        "torques": torques,
        "saturated_fraction": float(saturated / max(1, controls * max(1, len(r.actuators)))),
    }


def executed(task, sol, r: PlaybackResult):
    """The executed motion as a plan-shaped trajectory, for the task's metrics and goal: the
    actual state at each plan time (playback time (t_k - t_0) / speed), except that the last
    state is where the robot left things at rest (the end of the hold, when there is one).
    t: [N+1], X: [N+1, nx], U: [N, nu] (the plan's inputs)."""

    tau = (np.asarray(sol.t, float) - float(sol.t[0])) / r.settings.speed
    idx = np.clip(np.searchsorted(r.t, tau - 1e-9), 0, len(r.t) - 1)
    X = np.array(r.X[idx], float)
    if r.hold is not None and len(r.hold.X):
        X[-1] = r.hold.X[-1]
    return SimpleNamespace(t=np.asarray(sol.t, float), X=X, U=np.asarray(sol.U, float))


def executed_goal(task, sol, r: PlaybackResult) -> dict:
    """The task's metrics on the executed motion (``executed``) and its goal judged on them:
    {"metrics": ..., "goal": {met, checks, judged}} (``judged`` false for a smoke-sized plan,
    as its solve recorded); a metric the truth state cannot give is an error entry (and fails
    the checks that need it)."""

    try:
        m = metrics.compute(task, executed(task, sol, r))
    except (RuntimeError, SimulationError, ValueError) as e:
        m = {"error": str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__}
    return {"metrics": m, "goal": judge(task.config, m)}
