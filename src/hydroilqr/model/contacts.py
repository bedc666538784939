"""Contact facts of a task's model, from geometry queries and contact solves of given states:
which geometry pairs touch along a trajectory (``timeline``, ``touched_pairs``), which bodies
the cost tracks and which of them only contact can move (``tracked_objects``), and what to do
when nothing touches them (``no_contact_remedy``: ``check``'s warning, ``solve``'s sentence)."""

from __future__ import annotations

import numpy as np
from pydrake.multibody.tree import JointIndex

from hydroilqr.model.names import body_labels


def _normal_force_hydro(info) -> float:
    """Normal force of a hydroelastic contact: the force along the area-weighted mean normal
    of its surface."""
    s = info.contact_surface()
    F = np.asarray(info.F_Ac_W().translational())
    n = np.zeros(3)
    for i in range(s.num_faces()):
        n += s.area(i) * np.asarray(s.face_normal(i))
    norm = np.linalg.norm(n)
    return float(abs(F @ n) / norm) if norm > 0 else float(np.linalg.norm(F))


def timeline(task, X: np.ndarray, U: np.ndarray | None):
    """Contact of every state of X: [T, nx] stepped with U: [T-1, nu] (or fewer rows / None:
    the states without a control contribute contact from a geometry query, no force).

    Returns (pairs: list of ((geom A, geom B), (body A, body B)) in order of first contact,
    on: [T, P] bool, force: [T, P] peak normal force per state (0 without a step))."""
    dyn = task.dynamics
    plant = dyn.plant
    names = dyn.geometry_names()
    unknown = ("?", "?")
    X = np.asarray(X)
    U = np.zeros((0, dyn.nu)) if U is None else np.asarray(U)
    if U.ndim != 2 or U.shape[1] != dyn.nu:
        U = np.zeros((0, dyn.nu))
    index: dict = {}
    pairs: list = []
    rows: list[dict] = []
    port = plant.get_contact_results_output_port()

    def add(row, ida, idb, f):
        a, b = names.get(ida, unknown), names.get(idb, unknown)
        key = (a[0], b[0]) if a[0] <= b[0] else (b[0], a[0])
        if key not in index:
            index[key] = len(pairs)
            pairs.append((key, (a[1], b[1]) if key[0] == a[0] else (b[1], a[1])))
        j = index[key]
        row[j] = max(row.get(j, 0.0), f)

    for k, x in enumerate(X):
        row: dict = {}
        if k < len(U) and k < len(X) - 1:
            plant.SetPositionsAndVelocities(dyn.plant_context, x)
            dyn._input.FixValue(dyn.context, U[k])
            results = port.Eval(dyn.plant_context)
            for i in range(results.num_hydroelastic_contacts()):
                info = results.hydroelastic_contact_info(i)
                s = info.contact_surface()
                add(row, s.id_M(), s.id_N(), _normal_force_hydro(info))
            for i in range(results.num_point_pair_contacts()):
                info = results.point_pair_contact_info(i)
                pp = info.point_pair()
                f = float(abs(np.asarray(info.contact_force()) @ np.asarray(pp.nhat_BA_W)))
                add(row, pp.id_A, pp.id_B, f)
        else:
            surfaces, points = dyn.contact_query(x)
            for s in surfaces:
                add(row, s.id_M(), s.id_N(), 0.0)
            for pp in points:
                add(row, pp.id_A, pp.id_B, 0.0)
        rows.append(row)
    on = np.zeros((len(X), len(pairs)), bool)
    force = np.zeros((len(X), len(pairs)))
    for k, row in enumerate(rows):
        for j, f in row.items():
            on[k, j] = True
            force[k, j] = f
    return pairs, on, force


def runs(on: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index of every run of True in ``on``."""
    out = []
    k = 0
    while k < len(on):
        if on[k]:
            j = k
            while j + 1 < len(on) and on[j + 1]:
                j += 1
            out.append((k, j))
            k = j + 1
        else:
            k += 1
    return out


def touched_pairs(task, X: np.ndarray | None = None, steps: int | None = None) -> list[dict]:
    """Pairs that touch along X: [T, nx] (default: a rollout of the task's initial guess from
    x0 over ``steps`` steps, default the task's): [{pair, bodies, steps}] in order of first
    contact. A geometry query per state: no contact solve beyond the rollout's own."""
    if X is None:
        N = task.steps if steps is None else int(steps)
        X = task.dynamics.rollout(task.x0, task.initial_guess(N))
    pairs, on, _ = timeline(task, X, None)
    return [
        {"pair": list(key), "bodies": list(bodies), "steps": int(np.sum(on[:, j]))}
        for j, (key, bodies) in enumerate(pairs)
    ]


def tracked_bodies(task) -> set[str]:
    """Bodies whose motion the cost weighs: the bodies moved by every joint (floating ones
    included) with a state weight > 0 in cost.Q or cost.Qf."""
    dyn = task.dynamics
    plant = dyn.plant
    nv = dyn.nv
    w = np.asarray(task.cost.q) + np.asarray(task.cost.qf)
    joints = []
    for i in range(plant.num_joints()):
        j = plant.get_joint(JointIndex(i))
        v0, n = j.velocity_start(), j.num_velocities()
        if n and (np.any(w[v0 : v0 + n] > 0) or np.any(w[nv + v0 : nv + v0 + n] > 0)):
            joints.append(j.index())
    if not joints:
        return set()
    labels = body_labels(plant)
    return {labels[int(b)] for b in plant.GetBodiesKinematicallyAffectedBy(joints)}


def tracked_objects(task) -> set[str]:
    """The tracked bodies (``tracked_bodies``) that the robot can move only through contact:
    neither moved by an actuated joint nor on the path from the world to one (a robot's own
    links and base are excluded), and not welded to the world. A pushed ball or block."""
    plant = task.dynamics.plant
    parent = {}
    for i in range(plant.num_joints()):
        j = plant.get_joint(JointIndex(i))
        parent[j.child_body().index()] = j.parent_body().index()
    actuated = [plant.get_joint_actuator(i).joint() for i in plant.GetJointActuatorIndices()]
    robot = set(plant.GetBodiesKinematicallyAffectedBy([j.index() for j in actuated]))
    for j in actuated:
        b = j.parent_body().index()
        while b in parent and b not in robot:
            robot.add(b)
            b = parent[b]
    robot |= {b.index() for b in plant.GetBodiesWeldedTo(plant.world_body())}
    labels = body_labels(plant)
    return tracked_bodies(task) - {labels[int(b)] for b in robot}


def fixed_bodies(task) -> set[str]:
    """The world and the bodies welded to it (the ground, a table, a wall): touching them
    moves nothing the robot could push."""
    plant = task.dynamics.plant
    labels = body_labels(plant)
    return {labels[int(b.index())] for b in plant.GetBodiesWeldedTo(plant.world_body())} | {"world"}


#: What to do when no moving body touches a tracked object along the initial guess (solve's
#: status sentence and check's warning say the same).
NO_CONTACT_REMEDY = (
    "give an initial guess that moves the robot into contact with it (an initial_guess file: "
    "docs/task-format.md) or start them touching; a closer start alone does not help"
)


def touches_moving(pairs: list[dict], tracked: set[str], fixed: set[str]) -> bool:
    """Some pair of ``pairs`` ([{bodies: [a, b], ...}], as from ``touched_pairs``) has a
    tracked body touching a body that moves (not one of ``fixed``)."""
    for p in pairs:
        a, b = p["bodies"]
        if (a in tracked and b not in fixed and b != a) or (
            b in tracked and a not in fixed and a != b
        ):
            return True
    return False


#: Scales of the guess's commands tried by ``cost_pull_contact``: halfway to, and at, the
#: commands the control cost alone prefers (zero).
PULL_SCALES = (0.5, 0.0)


def cost_pull_contact(task, U: np.ndarray) -> dict | None:
    """Whether the cost itself moves the robot to a tracked object when the guess's rollout
    (controls U: [N, nu]) touches none: the control cost R·u² pulls the commands towards 0,
    so the solver's first steps take the guess's commands towards 0 whatever contact there is
    (an arm held up by gravity-compensating torques sags onto the ball below it). Returns
    {scale, pairs} of the first scale of PULL_SCALES whose rollout has a moving body touch a
    tracked object (pairs: those touching it), or None (no R, or no such touch)."""
    tracked, fixed = tracked_objects(task), fixed_bodies(task)
    U = np.asarray(U, float)
    if not tracked or not np.any(np.asarray(task.cost.r) > 0) or not np.any(U):
        return None
    for s in PULL_SCALES:
        try:
            X = task.dynamics.rollout(task.x0, s * U)
        except Exception:  # (a rollout that fails: no evidence either way)
            continue
        pairs = touched_pairs(task, X)
        if touches_moving(pairs, tracked, fixed):
            hits = [
                p
                for p in pairs
                if set(p["bodies"]) & tracked and not set(p["bodies"]) <= fixed | tracked
            ]
            return {"scale": s, "pairs": [p["pair"] for p in hits]}
    return None


def touches_tracked(task, X: np.ndarray) -> bool:
    """Some state of X: [T, nx] has a tracked body touching a body that moves (not the world
    or what is welded to it, such as the ground)."""
    return touches_moving(touched_pairs(task, X), tracked_objects(task), fixed_bodies(task))


def no_contact_remedy(task, X: np.ndarray | None = None, names: str = "the object") -> str:
    """What to do when no contact along the guess gives the solver no gradient (``check``'s
    warning and ``solve``'s no-progress sentence): an approach term (a ``distance`` term with
    ``max``) in a first continuation stage, dropped later, or a guess that moves; a closer
    start alone does not help. If the task has an approach term: before a solve (``X`` None),
    that it is there for this; after a solve whose states ``X`` [T, nx] touch nothing, how to
    strengthen it."""
    approach = approach_terms(task)
    if approach:
        which = f"the approach term{'s' if len(approach) > 1 else ''} {', '.join(approach)}"
        if X is None:
            return f"{which} (cost.terms) should bring them into contact first"
        if not touches_tracked(task, X):
            return (
                f"{which} did not bring them into contact: give it more weight, a max below "
                "0 (a touch, not a near miss) and a window that starts when the robot can be "
                "there, or an initial guess that moves the robot into contact"
            )
    return (
        "add an approach term (a distance term in cost.terms between the robot's geometry and "
        f"{names}, with max slightly below 0) in a first continuation stage, with weight 0 in "
        "the task as written, or give an initial guess that moves the robot into contact; a "
        'closer start alone does not help (docs/guide.md, "From no contact to contact")'
    )


def approach_terms(task) -> list[str]:
    """Names of the approach terms (distance terms with a ``max`` or a ``target``, not a
    clearance ``min`` alone) with a positive weight in the task or one of its continuation
    stages."""
    tasks = [task]
    try:
        tasks += task.stages()
    except Exception:  # (a stage that does not build: its error is reported elsewhere)
        pass
    names = []
    for t in tasks:
        for term in t.config.cost.terms:
            pulls = term.pulls_toward_contact()  # (a distance's max or target)
            if pulls and np.any(np.asarray(term.weight, float) > 0):
                if term.name not in names:
                    names.append(term.name)
    return names
