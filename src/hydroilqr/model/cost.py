"""Quadratic cost of paper eq. (3a), with named, weighted terms.

    J = Σ_{k<N} [ x̃_kᵀ Q x̃_k + u_kᵀ R u_k ] + x̃_Nᵀ Q_f x̃_N,   x̃_k = x_k ⊖ x_nom(t_k)

``⊖`` is the tangent-space difference of ``state.StateLayout`` (on quaternion blocks
2 sin(θ/2)·axis, the rotation vector to first order), so Q and Q_f are diagonal over the
tangent space (size 2 nv) and given per named block in the task file. The nominal may move
linearly in time,
``x_nom(t) = nominal + nominal_rate · min(t, nominal_rate_until)`` (e.g. a base position
advancing at a target speed, then holding), with the blocks of ``nominal_relative_to_start``
offset by their values in the task's initial state, or follow a solved run
(``cost.reference``: its states X_ref(t), linearly interpolated in time with quaternions
renormalized, held after its end) on some or all blocks.
With ``nominal_time: horizon_end`` every step of a solve over [t0, t_N] is measured against
x_nom(t_N) instead: a fixed goal at the horizon's end, which moves forward with each
receding-horizon window (the paper's public cheetah code sets its target this way).

``quadratize`` returns the derivatives iLQR needs in Drake's coordinates: with
``r = x ⊖ x_nom`` and ``Jr = ∂r/∂x``, ``l_x = 2 Jrᵀ Q r`` and ``l_xx = 2 Jrᵀ Q Jr``
(Gauss-Newton on quaternion blocks, exact elsewhere).

Task-space terms (``cost.terms``: positions, velocities and heights of points on bodies, frame
orientations, distances between geometries; ``model/terms.py``) are added to these when a task
has them (``task_terms``): their costs to each step's, their Gauss-Newton derivatives to l_x
and l_xx, their values to ``breakdown`` as ``terms.<name>``. Without them nothing changes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hydroilqr.io.rundir import read_run_arrays
from hydroilqr.model.state import StateLayout
from hydroilqr.model.terms import TaskSpaceTerms
from hydroilqr.problem.cost import CostConfig
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.inputs import MAX_JSON_BYTES, read_bounded


@dataclass
class Quadratization:
    """Cost derivatives along a trajectory.

    lx: [N+1, nx], lxx: [N+1, nx, nx], lu: [N, nu], luu: [N, nu, nu].
    """

    lx: np.ndarray
    lxx: np.ndarray
    lu: np.ndarray
    luu: np.ndarray


class QuadraticCost:
    """Diagonal quadratic cost. q, qf: [2 nv] tangent weights; r: [nu]; x_nom: [nx]."""

    def __init__(
        self,
        layout: StateLayout,
        q,
        qf,
        r,
        x_nom,
        rate,
        dt: float,
        terms: dict[str, tuple[str, tuple[int, ...]]] | None = None,
        nominal_time: str = "step",
    ):
        self.layout = layout
        self.q = np.asarray(q, float)
        self.qf = np.asarray(qf, float)
        self.r = np.asarray(r, float)
        self.x_nom = np.asarray(x_nom, float)
        self.rate = np.asarray(rate, float)
        self.dt = dt
        self.terms = terms or {}
        self.nominal_time = nominal_time
        self.task_terms = None  # model.terms.TaskSpaceTerms, when the task has cost.terms

    @staticmethod
    def from_config(
        layout: StateLayout,
        cfg: CostConfig,
        dt: float,
        resolve=None,
        models=None,
        dynamics=None,
        x0=None,
        end_time: float = 0.0,
    ) -> QuadraticCost:
        """``resolve(path) -> Path`` locates ``cfg.reference`` (default: as given); ``models``
        (the task's model files) must match the reference run's, when its summary names them.
        ``cfg.terms`` need the plant (``dynamics``), the initial state ``x0`` and the task's
        ``end_time`` (model/terms.py)."""
        q = layout.tangent_vector(cfg.Q, "cost.Q")
        qf = layout.tangent_vector(cfg.Qf, "cost.Qf")
        r = QuadraticCost._control_weights(layout, cfg.R)
        if not np.all(np.isfinite(r)) or np.any(r < 0):
            raise ConfigError("cost.R: weights must be finite and non-negative")
        x_nom = layout.coordinate_vector(cfg.nominal, "cost.nominal", layout.default_nominal())
        if cfg.nominal_relative_to_start:
            if x0 is None and dynamics is None:
                raise ConfigError("cost.nominal_relative_to_start: needs the task's initial state")
            start = dynamics.initial_state() if x0 is None else np.asarray(x0, float)
            x_nom = QuadraticCost._relative_to_start(layout, cfg, x_nom, start)
        rate = QuadraticCost._nominal_rate(layout, cfg.nominal_rate)
        if cfg.running_cost_dt:
            q, r = q * dt, r * dt
        terms = QuadraticCost._terms(layout, cfg)
        cost = QuadraticCost(layout, q, qf, r, x_nom, rate, dt, terms, cfg.nominal_time)
        cost.rate_until = cfg.nominal_rate_until
        if cfg.reference:
            cost.set_reference(*_load_reference(layout, cfg, resolve, models), cfg.reference_blocks)
        elif cfg.reference_blocks:
            raise ConfigError("cost.reference_blocks: given without cost.reference")
        if cfg.terms:
            if dynamics is None:
                raise ConfigError("cost.terms: task-space terms need the task's plant")
            x0 = dynamics.initial_state() if x0 is None else x0
            cost.task_terms = TaskSpaceTerms(
                dynamics, cfg.terms, dt, cfg.running_cost_dt, x0, end_time
            )
        return cost

    @staticmethod
    def _control_weights(layout: StateLayout, R) -> np.ndarray:
        """r: [nu] from cost.R: a number, one per actuator, or a mapping actuator -> weight."""
        nu = len(layout.actuators)
        if isinstance(R, dict):
            r = np.zeros(nu)
            for name, w in R.items():
                name = getattr(layout, "actuator_aliases", {}).get(name, name)
                if name not in layout.actuators:
                    raise ConfigError(
                        f"cost.R.{name}: unknown actuator (known: {', '.join(layout.actuators)})"
                    )
                try:
                    r[layout.actuators.index(name)] = float(w)
                except (TypeError, ValueError):
                    raise ConfigError(f"cost.R.{name}: expected a number, got {w!r}") from None
            return r
        try:
            vals = np.asarray(R, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise ConfigError(f"cost.R: expected numbers, got {R!r}") from None
        if np.ndim(R) == 0:  # a number applies to every actuator
            vals = np.full(nu, vals[0])
        if vals.size != nu:
            want = "1 value" if nu == 1 else f"a number or {nu} values (one per actuator)"
            raise ConfigError(f"cost.R: expected {want}, got a list of {vals.size}")
        return vals

    @staticmethod
    def _relative_to_start(layout: StateLayout, cfg: CostConfig, x_nom, x0) -> np.ndarray:
        """x_nom with the blocks of cfg.nominal_relative_to_start shifted by their values in
        the initial state x0 (``nominal`` gives the offset; 0 when it does not name them)."""
        x_nom = np.array(x_nom, float)
        key = "cost.nominal_relative_to_start"
        for name in cfg.nominal_relative_to_start:
            b = layout.block(name, f"{key}.{name}")
            if b.kind == "quaternion":
                raise ConfigError(f"{key}.{name}: not supported for orientations")
        for name in cfg.nominal_relative_to_start:
            c = list(layout.block(name).coords)
            x_nom[c] += x0[c]
        return x_nom

    @staticmethod
    def _nominal_rate(layout: StateLayout, nominal_rate: dict) -> np.ndarray:
        """rate: [nx], the nominal's rate of change per block of cost.nominal_rate."""
        rate = np.zeros(layout.nx)
        for name, v in nominal_rate.items():
            b = layout.block(name, f"cost.nominal_rate.{name}")
            if b.kind == "quaternion":
                raise ConfigError(f"cost.nominal_rate.{name}: not supported for orientations")
            vals = np.asarray(v, float).reshape(-1)  # numbers: checked by config.validate
            if np.ndim(v) == 0:
                vals = np.full(len(b.coords), vals[0])
            if vals.size != len(b.coords):
                raise ConfigError(
                    f"cost.nominal_rate.{name}: expected a number or {len(b.coords)} values, "
                    f"got a list of {vals.size}"
                )
            rate[list(b.coords)] = vals
        return rate

    @staticmethod
    def _terms(layout: StateLayout, cfg: CostConfig) -> dict:
        """Term name ("Q.<block>", "Qf.<block>") -> (section, the tangent indices it weights)."""
        terms = {}
        for section in ("Q", "Qf"):
            # Each coordinate belongs to the last named block that set its weight (the weight
            # in effect), so overlapping blocks (a group and a member) are not counted twice.
            owner: dict[int, str] = {}
            for name in getattr(cfg, section):
                owner.update(dict.fromkeys(layout.block(name).tangent, name))
            for name in getattr(cfg, section):
                idx = tuple(i for i in layout.block(name).tangent if owner[i] == name)
                terms[f"{section}.{name}"] = (section, idx)
        return terms

    def set_reference(self, t: np.ndarray, X: np.ndarray, blocks: list[str]) -> None:
        """Track X: [M, nx] at times t: [M] on ``blocks`` (all if empty)."""
        names = blocks or list(self.layout.primitives)
        mask = np.zeros(self.layout.nx, bool)
        for name in names:
            mask[list(self.layout.block(name, f"cost.reference_blocks.{name}").coords)] = True
        self.ref_t, self.ref_X, self.ref_mask = np.asarray(t, float), np.asarray(X, float), mask

    # ------------------------------------------------------------------------------------
    rate_until: float | None = None  # cost.nominal_rate_until
    ref_t: np.ndarray | None = None
    ref_X: np.ndarray | None = None
    ref_mask: np.ndarray | None = None

    def nominal(self, t: np.ndarray) -> np.ndarray:
        """x_nom at times t: [T] -> [T, nx]."""
        t = np.asarray(t, float)
        tr = t if self.rate_until is None else np.minimum(t, self.rate_until)
        x = self.x_nom[None, :] + tr[:, None] * self.rate[None, :]
        if self.ref_X is not None:
            # Linear interpolation in time (held at the ends); quaternions renormalized.
            rt = self.ref_t
            tc = np.clip(t, rt[0], rt[-1])
            i = np.clip(np.searchsorted(rt, tc, side="right") - 1, 0, max(len(rt) - 2, 0))
            j = np.minimum(i + 1, len(rt) - 1)
            span = rt[j] - rt[i]
            w = np.divide(tc - rt[i], span, out=np.zeros_like(tc), where=span > 0)[:, None]
            ref = (1.0 - w) * self.ref_X[i] + w * self.ref_X[j]
            for b in self.layout.quaternions:
                c = list(b.coords)
                ref[:, c] /= np.linalg.norm(ref[:, c], axis=1, keepdims=True)
            x[:, self.ref_mask] = ref[:, self.ref_mask]
        return x

    def times(self, N: int, t0: float) -> np.ndarray:
        return t0 + self.dt * np.arange(N + 1)

    def targets(self, N: int, t0: float) -> np.ndarray:
        """The nominal each step of an N-step solve from t0 is measured against: [N+1, nx]."""
        t = self.times(N, t0)
        if self.nominal_time == "horizon_end":
            t = np.full_like(t, t[-1])
        return self.nominal(t)

    def stage_costs(self, X: np.ndarray, U: np.ndarray, t0: float = 0.0) -> np.ndarray:
        """Cost of each step (last entry is the terminal cost). X: [N+1, nx], U: [N, nu]."""
        N = U.shape[0]
        R = self.layout.diff(X, self.targets(N, t0))  # [N+1, 2nv]
        c = np.empty(N + 1)
        with np.errstate(over="ignore", invalid="ignore"):  # overflow: inf, seen by callers
            c[:N] = np.einsum("ki,i,ki->k", R[:N], self.q, R[:N]) + np.einsum(
                "ki,i,ki->k", U, self.r, U
            )
            c[N] = R[N] @ (self.qf * R[N])
            if self.task_terms is not None:
                c += self.task_terms.stage_costs(X, t0)
        return c

    def total(self, X: np.ndarray, U: np.ndarray, t0: float = 0.0) -> float:
        """Cost (3a) of X: [N+1, nx], U: [N, nu] starting at time t0."""
        with np.errstate(over="ignore", invalid="ignore"):
            return float(np.sum(self.stage_costs(X, U, t0)))

    def breakdown(self, X: np.ndarray, U: np.ndarray, t0: float = 0.0) -> dict[str, float]:
        """Value of each named term (Q.<block>, Qf.<block>, R). X: [N+1, nx], U: [N, nu]."""
        N = U.shape[0]
        R = self.layout.diff(X, self.targets(N, t0))
        out = {}
        for name, (section, idx) in self.terms.items():
            idx = list(idx)
            if section == "Q":
                out[name] = float(np.sum(R[:N, idx] ** 2 * self.q[idx]))
            else:
                out[name] = float(np.sum(R[N, idx] ** 2 * self.qf[idx]))
        out["R"] = float(np.sum(U**2 * self.r))
        if self.task_terms is not None:
            out.update(self.task_terms.breakdown(X, t0))
        return out

    def quadratize(self, X: np.ndarray, U: np.ndarray, t0: float = 0.0) -> Quadratization:
        """Gradients and Gauss-Newton Hessians of the cost along X: [N+1, nx], U: [N, nu]:
        lx [N+1, nx], lu [N, nu], lxx [N+1, nx, nx], luu [N, nu, nu] (in x coordinates)."""
        N = U.shape[0]
        Xn = self.targets(N, t0)
        R = self.layout.diff(X, Xn)  # [N+1, 2nv]
        W = np.empty_like(R)
        W[:N] = self.q
        W[N] = self.qf
        if self.layout.quaternions:
            J = self.layout.diff_jacobian(X, Xn)  # [N+1, 2nv, nx]
            lx = 2.0 * np.einsum("kij,ki->kj", J, W * R)
            lxx = 2.0 * np.einsum("kij,ki,kil->kjl", J, W, J)
        else:
            # No quaternions: the tangent space is a permutation of the coordinates.
            c, t = self.layout.euclidean_index()
            nx = self.layout.nx
            lx = np.zeros((N + 1, nx))
            lx[:, c] = 2.0 * W[:, t] * R[:, t]
            lxx = np.zeros((N + 1, nx, nx))
            lxx[:, c, c] = 2.0 * W[:, t]
        if self.task_terms is not None:
            tx, txx = self.task_terms.quadratize(X, t0)
            lx, lxx = lx + tx, lxx + txx
        lu = 2.0 * U * self.r
        luu = np.zeros((N, U.shape[1], U.shape[1]))
        iu = np.arange(U.shape[1])
        luu[:, iu, iu] = 2.0 * self.r
        return Quadratization(lx, lxx, lu, luu)


def _load_reference(
    layout: StateLayout, cfg: CostConfig, resolve, models=None
) -> tuple[np.ndarray, np.ndarray]:
    arrays, path = read_run_arrays(
        resolve(cfg.reference) if resolve else cfg.reference, ("X", "t"), "cost.reference"
    )
    theirs = _run_models(path.parent)
    if models is not None and theirs is not None:
        mine = sorted(Path(m).name for m in models)
        if mine != theirs:
            raise ConfigError(
                f"cost.reference: {path.parent} is a run of other models ({', '.join(theirs)}), "
                f"not this task's ({', '.join(mine)})"
            )
    X, t = np.asarray(arrays["X"], float), np.asarray(arrays["t"], float)
    if X.ndim != 2 or X.shape[1] != layout.nx or t.shape != (X.shape[0],):
        raise ConfigError(
            f"cost.reference: {path} holds states of shape {X.shape}, not [M, {layout.nx}]"
        )
    if not np.all(np.isfinite(X)):
        raise ConfigError(f"cost.reference: {path} holds NaN or infinite states")
    return t, X


def _run_models(run_dir: Path) -> list[str] | None:
    """File names of the models a run's summary.json records (None: not recorded)."""
    try:
        text = read_bounded(run_dir / "summary.json", "summary", MAX_JSON_BYTES)
        models = json.loads(text)["config"]["models"]
        return sorted(Path(m["file"]).name for m in models)
    except (OSError, ValueError, KeyError, TypeError):
        return None
