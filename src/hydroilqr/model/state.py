"""Named layout of the state x = [q; v] and a quaternion-aware state difference.

Every joint of the plant contributes *primitive blocks*:

* a 1-DoF joint ``J`` (revolute, prismatic, ...): position block ``J`` and velocity block ``J.v``;
* a floating body ``B`` (quaternion floating joint): ``B.orientation`` (4 quaternion
  coordinates wxyz, 3 tangent coordinates), ``B.position`` (3), ``B.angular_velocity`` (3) and
  ``B.velocity`` (3);
* any other multi-DoF joint ``J``: ``J`` (positions) and ``J.v`` (velocities).

Each coordinate of a multi-coordinate euclidean block is also a one-coordinate *component*:
``B.position.x`` (``.y``, ``.z``; likewise ``B.velocity.*`` and ``B.angular_velocity.*``) of a
floating body, and ``J.SUFFIX`` of another multi-DoF joint with Drake's coordinate suffixes
(a planar joint: ``J.x``, ``J.y``, ``J.qz``, ``J.vx``, ``J.vy``, ``J.wz``). Components are
found by name but not listed among the blocks.

A task may name *groups* of primitive blocks or components (``blocks: {arm_q: [joint_1, ...,
joint_7]}``) and use any of these names for weights, nominal values and initial states.

The difference ``dx = x ⊖ x_ref`` lives in the tangent space, of size ``2 nv``: plain
subtraction everywhere except quaternion blocks, whose error is
``e = 2 sign(w) vec(q_ref* ⊗ q) = 2 sin(θ/2) · axis`` for a rotation by θ about ``axis``: the
rotation vector θ·axis to first order (the log map's small-angle form), but shorter at large
angles (|e| = 1.41 at 90°, 2 at 180°; ``final_error`` of an orientation block reports |e|, not
radians).
``diff_jacobian`` returns ``∂dx/∂x`` so costs in the tangent space can be pulled back to the
coordinates in which Drake's dynamics are linearized.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.multibody.tree import JointIndex

from hydroilqr.model.names import SCOPE, actuator_labels, actuator_names, bare, body_labels
from hydroilqr.problem.errors import ConfigError


@dataclass(frozen=True)
class Block:
    """One named piece of the state.

    ``coords``: indices into x (size nx). ``tangent``: indices into the tangent vector (2 nv).
    ``kind``: "euclidean" or "quaternion" (4 coords, 3 tangent).
    """

    name: str
    coords: tuple[int, ...]
    tangent: tuple[int, ...]
    kind: str = "euclidean"


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions (wxyz). a, b: [..., 4]."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_conj(q: np.ndarray) -> np.ndarray:
    """Conjugate of quaternions q: [..., 4] (w, x, y, z)."""
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def left_mul_matrix(a: np.ndarray) -> np.ndarray:
    """L(a) such that a ⊗ b = L(a) b. a: [..., 4] -> [..., 4, 4]."""
    w, x, y, z = np.moveaxis(a, -1, 0)
    return np.stack(
        [
            np.stack([w, -x, -y, -z], -1),
            np.stack([x, w, -z, y], -1),
            np.stack([y, z, w, -x], -1),
            np.stack([z, -y, x, w], -1),
        ],
        -2,
    )


def _aliases(prefixes: list[tuple[str, str, str]], names: list[str]) -> dict[str, str]:
    """Other names -> block name: ``MODEL::BARE...`` for every block, and ``BARE...`` for a
    scoped block where no other block has that bare name. ``prefixes``: (the name a joint's
    blocks start with, its model, its bare name)."""
    full: dict[str, str] = {}
    loose: dict[str, list[str]] = {}
    for prefix, model, short in prefixes:
        for n in names:
            if n == prefix or n.startswith(prefix + "."):
                rest = n[len(prefix) :]
                full[f"{model}{SCOPE}{short}{rest}"] = n
                if prefix != short:
                    loose.setdefault(f"{short}{rest}", []).append(n)
    out = {k: v for k, v in full.items() if k not in names}
    out.update({k: v[0] for k, v in loose.items() if len(v) == 1 and k not in names})
    return out


class StateLayout:
    """The state's named blocks. Built from a finalized MultibodyPlant by ``from_plant``."""

    def __init__(
        self,
        nq: int,
        nv: int,
        primitives: list[Block],
        actuators: list[str],
        components: list[Block] = (),
    ):
        self.nq, self.nv = nq, nv
        self.nx = nq + nv
        self.primitives = {b.name: b for b in primitives}
        # One-coordinate blocks inside multi-coordinate primitives (``base_joint.x``,
        # ``body.position.z``): addressable by name like any block, not listed among them.
        self.components = {b.name: b for b in components if b.name not in self.primitives}
        self.groups: dict[str, Block] = {}
        self.actuators = list(actuators)
        self.quaternions = [b for b in primitives if b.kind == "quaternion"]
        # Other names of a block: MODEL::NAME..., and the bare name of a scoped block that
        # no other block has (``from_plant``).
        self.aliases: dict[str, str] = {}
        self.actuator_aliases: dict[str, str] = {}  # any name of an actuator -> its label

    @staticmethod
    def from_plant(plant) -> StateLayout:
        nq, nv = plant.num_positions(), plant.num_velocities()
        blocks: list[Block] = []
        components: list[Block] = []
        joints = [plant.get_joint(JointIndex(i)) for i in range(plant.num_joints())]
        joints = [j for j in joints if j.num_positions() > 0 or j.num_velocities() > 0]
        names = [j.name() for j in joints]
        bodies = body_labels(plant)
        prefixes = []  # (name used, model, bare name) per joint, for the aliases
        for j in joints:
            name = j.name()
            model = plant.GetModelInstanceName(j.model_instance())
            if names.count(name) > 1:
                name = f"{model}{SCOPE}{name}"
            if j.type_name() == "quaternion_floating":  # named by its body's label
                label = bodies[int(j.child_body().index())]
                name = label if SCOPE in label else name
            prefixes.append((name, model, bare(name)))
            q0, nqj = j.position_start(), j.num_positions()
            v0, nvj = j.velocity_start(), j.num_velocities()
            if j.type_name() == "quaternion_floating":
                blocks += [
                    Block(
                        f"{name}.orientation",
                        tuple(range(q0, q0 + 4)),
                        tuple(range(v0, v0 + 3)),
                        "quaternion",
                    ),
                    Block(
                        f"{name}.position",
                        tuple(range(q0 + 4, q0 + 7)),
                        tuple(range(v0 + 3, v0 + 6)),
                    ),
                    Block(
                        f"{name}.angular_velocity",
                        tuple(range(nq + v0, nq + v0 + 3)),
                        tuple(range(nv + v0, nv + v0 + 3)),
                    ),
                    Block(
                        f"{name}.velocity",
                        tuple(range(nq + v0 + 3, nq + v0 + 6)),
                        tuple(range(nv + v0 + 3, nv + v0 + 6)),
                    ),
                ]
                for i, axis in enumerate("xyz"):  # body.position.x, ..., body.velocity.z
                    components += [
                        Block(f"{name}.position.{axis}", (q0 + 4 + i,), (v0 + 3 + i,)),
                        Block(f"{name}.angular_velocity.{axis}", (nq + v0 + i,), (nv + v0 + i,)),
                        Block(f"{name}.velocity.{axis}", (nq + v0 + 3 + i,), (nv + v0 + 3 + i,)),
                    ]
            else:
                if nqj != nvj:
                    raise ConfigError(
                        f"joint {name}: type {j.type_name()} has nq != nv; not supported"
                    )
                blocks += [
                    Block(name, tuple(range(q0, q0 + nqj)), tuple(range(v0, v0 + nvj))),
                    Block(
                        f"{name}.v",
                        tuple(range(nq + v0, nq + v0 + nvj)),
                        tuple(range(nv + v0, nv + v0 + nvj)),
                    ),
                ]
                if nqj > 1:  # Drake's coordinate names: planar_joint.x, .y, .qz, .vx, .vy, .wz
                    for i in range(nqj):
                        components += [
                            Block(f"{name}.{j.position_suffix(i)}", (q0 + i,), (v0 + i,)),
                            Block(f"{name}.{j.velocity_suffix(i)}", (nq + v0 + i,), (nv + v0 + i,)),
                        ]
        layout = StateLayout(nq, nv, blocks, actuator_labels(plant), components)
        layout.aliases = _aliases(prefixes, [b.name for b in blocks + components])
        index = {int(a.index()): k for k, a in enumerate(
            plant.get_joint_actuator(i) for i in plant.GetJointActuatorIndices()
        )}  # fmt: skip
        layout.actuator_aliases = {
            n: layout.actuators[index[int(a.index())]] for n, a in actuator_names(plant).items()
        }
        return layout

    # ---------------------------------------------------------------------------- names
    def add_groups(self, groups: dict[str, list[str]]) -> None:
        for gname, members in groups.items():
            if gname in self.primitives:
                raise ConfigError(f"blocks.{gname}: name clashes with a joint/body block")
            parts = []
            for m in members:
                m = self.aliases.get(m, m)
                part = self.primitives.get(m) or self.components.get(m)
                if part is None:
                    raise ConfigError(
                        f"blocks.{gname}: unknown joint/body block {m!r} "
                        f"(known: {', '.join(self.primitives)}{self._component_hint()})"
                    )
                parts.append(part)
            kinds = {p.kind for p in parts}
            if "quaternion" in kinds and len(parts) > 1:
                raise ConfigError(f"blocks.{gname}: a quaternion block cannot be grouped")
            self.groups[gname] = Block(
                gname,
                tuple(i for p in parts for i in p.coords),
                tuple(i for p in parts for i in p.tangent),
                parts[0].kind if parts else "euclidean",
            )

    def block(self, name: str, key: str = "") -> Block:
        name = self.aliases.get(name, name) if isinstance(name, str) else name
        if name in self.groups:
            return self.groups[name]
        if name in self.primitives:
            return self.primitives[name]
        if name in self.components:
            return self.components[name]
        known = list(self.groups) + list(self.primitives)
        raise ConfigError(
            f"{key or name}: unknown state block {name!r} (known: {', '.join(known)}"
            f"{self._component_hint()})"
        )

    def _component_hint(self) -> str:
        """'; components: a.x, ...' (a few) for an unknown-name error, or ''."""
        if not getattr(self, "components", None):
            return ""
        names = list(self.components)
        more = f", ... ({len(names)} in all)" if len(names) > 6 else ""
        return f"; components: {', '.join(names[:6])}{more}"

    def names(self) -> list[str]:
        return list(self.groups) + list(self.primitives)

    def describe(self) -> list[tuple[str, int, int, str]]:
        """(name, coordinate size, tangent size, kind) of every block, groups first."""
        return [
            (b.name, len(b.coords), len(b.tangent), b.kind)
            for b in list(self.groups.values()) + list(self.primitives.values())
        ]

    # ---------------------------------------------------------------------------- vectors
    def _numbers(self, name: str, value, key: str) -> tuple[Block, np.ndarray]:
        """The block ``name`` and ``value`` as a flat float array (ConfigError naming
        ``key.name`` if it is not numbers)."""
        b = self.block(name, f"{key}.{name}")
        try:
            return b, np.asarray(value, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise ConfigError(f"{key}.{name}: expected numbers, got {value!r}") from None

    def tangent_vector(self, spec: dict, key: str, default: float = 0.0) -> np.ndarray:
        """Weights by block name -> vector over the tangent space, shape [2 nv]."""
        w = np.full(2 * self.nv, float(default))
        for name, value in spec.items():
            b, vals = self._numbers(name, value, key)
            n = len(b.tangent)
            if np.ndim(value) == 0:  # a number applies to the whole block; a list must fit it
                vals = np.full(n, vals[0])
            if vals.size != n:
                want = "1 value" if n == 1 else f"a number or a list of {n} values"
                raise ConfigError(f"{key}.{name}: expected {want}, got a list of {vals.size}")
            w[list(b.tangent)] = vals
        return w

    def coordinate_vector(self, spec: dict, key: str, base: np.ndarray) -> np.ndarray:
        """Values by block name written into a copy of ``base`` (shape [nx])."""
        x = np.array(base, dtype=float)
        # In order: a later name overrides the coordinates an earlier one set (e.g. --set
        # initial_state.joint_2=... over a task's group arm_q).
        for name, value in spec.items():
            b, vals = self._numbers(name, value, key)
            n = len(b.coords)
            if np.ndim(value) == 0 and b.kind != "quaternion":
                vals = np.full(n, vals[0])
            if vals.size != n:
                want = (
                    "4 values, a quaternion [w, x, y, z]"
                    if b.kind == "quaternion"
                    else f"a number or {n} values"
                )
                raise ConfigError(f"{key}.{name}: expected {want}, got {vals.size}")
            if not np.all(np.isfinite(vals)):
                raise ConfigError(f"{key}.{name}: values must be finite")
            if b.kind == "quaternion":
                norm = np.linalg.norm(vals)
                if norm < 1e-9:
                    raise ConfigError(f"{key}.{name}: quaternion must be non-zero")
                vals = vals / norm
            x[list(b.coords)] = vals
        return x

    def default_nominal(self) -> np.ndarray:
        x = np.zeros(self.nx)
        for b in self.quaternions:
            x[b.coords[0]] = 1.0
        return x

    # ---------------------------------------------------------------------------- difference
    def diff(self, X: np.ndarray, Xref: np.ndarray) -> np.ndarray:
        """Tangent-space difference X ⊖ Xref. X, Xref: [..., nx] -> [..., 2 nv] (Xref
        broadcasts against X, e.g. one reference state for a whole trajectory). ValueError for
        other shapes."""
        X, Xref = self._states(X, Xref)
        out = np.zeros(X.shape[:-1] + (2 * self.nv,))
        idx_c, idx_t = self.euclidean_index()
        out[..., idx_t] = X[..., idx_c] - Xref[..., idx_c]
        for b in self.quaternions:
            qe = quat_mul(quat_conj(Xref[..., list(b.coords)]), X[..., list(b.coords)])
            s = np.where(qe[..., :1] < 0, -1.0, 1.0)
            out[..., list(b.tangent)] = 2.0 * s * qe[..., 1:]
        return out

    def diff_jacobian(self, X: np.ndarray, Xref: np.ndarray) -> np.ndarray:
        """∂(X ⊖ Xref)/∂X. X, Xref: [T, nx] -> [T, 2 nv, nx] (identity outside quaternions)."""
        X, Xref = self._states(X, Xref)
        if X.ndim != 2:
            raise ValueError(f"X must have shape [T, {self.nx}], got {X.shape}")
        T = X.shape[0]
        J = np.zeros((T, 2 * self.nv, self.nx))
        idx_c, idx_t = self.euclidean_index()
        J[:, idx_t, idx_c] = 1.0
        for b in self.quaternions:
            qref_c = quat_conj(Xref[:, list(b.coords)])
            L = left_mul_matrix(qref_c)  # [T, 4, 4]
            qe = np.einsum("tij,tj->ti", L, X[:, list(b.coords)])
            s = np.where(qe[:, 0] < 0, -1.0, 1.0)
            J[np.ix_(np.arange(T), list(b.tangent), list(b.coords))] = (
                2.0 * s[:, None, None] * L[:, 1:, :]
            )
        return J

    def _states(self, X, Xref) -> tuple[np.ndarray, np.ndarray]:
        """X: [..., nx] and Xref broadcast to its shape, as float arrays; ValueError naming
        the shapes otherwise."""
        X, Xref = np.asarray(X, dtype=float), np.asarray(Xref, dtype=float)
        for name, a in (("X", X), ("Xref", Xref)):
            if a.ndim == 0 or a.shape[-1] != self.nx:
                raise ValueError(f"{name} must have shape [..., {self.nx}] (nx), got {a.shape}")
        try:
            return X, np.broadcast_to(Xref, X.shape)
        except ValueError:
            raise ValueError(
                f"Xref {Xref.shape} does not broadcast to the shape of X {X.shape}"
            ) from None

    def euclidean_index(self) -> tuple[np.ndarray, np.ndarray]:
        """(state coordinates, tangent coordinates) of every non-quaternion entry: the
        coordinates where X ⊖ Xref is a plain difference, and where it lands in [2 nv]."""
        if not hasattr(self, "_euclid"):
            c, t = [], []
            for b in self.primitives.values():
                if b.kind == "euclidean":
                    c += b.coords
                    t += b.tangent
            self._euclid = (np.array(c, dtype=int), np.array(t, dtype=int))
        return self._euclid

    def normalize(self, x: np.ndarray, what: str = "state") -> np.ndarray:
        """A copy of x: [..., nx] with every quaternion block scaled to unit norm. ValueError
        for a zero quaternion."""
        x = np.array(x, dtype=float)
        for b in self.quaternions:
            q = x[..., list(b.coords)]
            norm = np.linalg.norm(q, axis=-1, keepdims=True)
            if not np.all(norm > 1e-9):
                raise ValueError(f"{what}: the quaternion of {b.name} must be non-zero")
            x[..., list(b.coords)] = q / norm
        return x
