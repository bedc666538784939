"""Task-space cost terms (``cost.terms``): each a residual composed with activations and a
time shaping, beside the quadratic terms of ``cost.py`` and in their convention (no ½).

A term is a ``Term``: its residual r(x) (model/residuals.py: one class per term type,
looked up by name in ``RESIDUALS``), what the cost squares (an activation of
model/activations.py: r itself, s − target, or the part of s beyond bounds), its weights
(``Quadratic``: ``f_k · Σ_i w_i r_i²`` at a step), its time shaping (model/windows.py: a window
``after``/``until`` with a ``ramp``, times the time step with ``running_cost_dt``, or the last
state, ``terminal``), and how the steps' costs add up over the window (``Sum``, or ``SoftMin``
with ``softmin`` τ > 0).

Derivatives are Gauss-Newton, ``l_x = 2 f Jᵀ W r`` and ``l_xx = 2 f Jᵀ W J`` with
``J = ∂r/∂x`` (∂r/∂s times the residual's Jacobian where the activation shapes s). One plant
context (of its own diagram context, for the geometry queries) is reused for every step; a
state is set once per step for all terms. Times are the task's (``t_k = t0 + k·dt``), so
windows and moving targets hold across receding-horizon windows.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hydroilqr.model.activations import Quadratic, SoftMin, Sum, softmin
from hydroilqr.model.residuals import RESIDUALS, Kinematics, Residual
from hydroilqr.model.windows import Terminal, Window, time_shaping
from hydroilqr.problem.terms import TermConfig

__all__ = ["TaskSpaceTerms", "Term", "build_term", "softmin"]


@dataclass
class Term:
    """One term, resolved against the plant: its residual composed with an activation
    (``shape``), its weights (``quadratic``), its time shaping (``time``) and how its steps'
    costs add up (``aggregate``)."""

    cfg: TermConfig
    residual: Residual
    shape: Any  # activations.Identity | Target | Bounds
    quadratic: Quadratic
    time: Terminal | Window
    aggregate: Sum | SoftMin

    @property
    def name(self) -> str:
        return self.cfg.name

    @property
    def weights(self) -> np.ndarray:
        return self.quadratic.weights

    @property
    def size(self) -> int:
        return self.residual.size

    def evaluate(self, kin: Kinematics, x: np.ndarray, time: float, jac: bool):
        """(r [m], J [m, nx] or None, the measured quantity) at the state x set in ``kin``."""
        s, measured, aux = self.residual.value(kin, x, time)
        r, d = self.shape(s)
        if not jac:
            return r, None, measured
        if d is None:
            return r, self.residual.jacobian(kin, x, aux), measured
        if not d.any():  # inside its bounds: no Jacobian needed
            return r, np.zeros((self.size, kin.nx)), measured
        return r, d[:, None] * self.residual.jacobian(kin, x, aux), measured


def build_term(cfg: TermConfig, kin: Kinematics) -> Term:
    """The term of ``cfg`` (a checked TermConfig) on the plant of ``kin``; ConfigError for a
    name the model does not have."""
    residual = RESIDUALS[cfg.type](cfg, kin, f"cost.terms.{cfg.name}")
    w = np.asarray(cfg.weight, float).reshape(-1)
    weights = np.full(residual.size, w[0]) if w.size == 1 else w
    return Term(
        cfg,
        residual,
        residual.activation(),
        Quadratic(weights),
        time_shaping(cfg.terminal, cfg.after, cfg.until, cfg.ramp),
        SoftMin(cfg.softmin) if cfg.softmin > 0 else Sum(),
    )


class TaskSpaceTerms:
    """The task's ``cost.terms`` on a plant. ``dynamics``: a ``plant.Dynamics``; ``x0``: the
    initial state (for ``relative_to_start``); ``end_time``: the task's end (s), where a
    window without ``until`` ends for its ramp."""

    def __init__(
        self,
        dynamics,
        configs: list[TermConfig],
        dt: float,
        running_cost_dt: bool,
        x0: np.ndarray,
        end_time: float,
    ):
        self.dynamics = dynamics
        self.kin = Kinematics(dynamics)
        self.nx = self.kin.nx
        self.dt = dt
        self.running_cost_dt = running_cost_dt
        self.end_time = float(end_time)
        self.terms = [build_term(c, self.kin) for c in configs]
        # [n_terms, 1]: terms that cost something (weight 0: left out of the cost's evaluation)
        self._weighted = np.array([bool(np.any(t.weights)) for t in self.terms])[:, None]
        self.kin.set(np.asarray(x0, float))
        for t in self.terms:
            t.residual.start(self.kin)

    # ------------------------------------------------------------------ over a trajectory
    def windows(self, N: int, t0: float, times=None) -> tuple[np.ndarray, np.ndarray]:
        """(active [n_terms, N+1] bool, factor [n_terms, N+1]): where each term counts in an
        N-step solve from t0 and its weight factor there (ramp × dt for running terms with
        running_cost_dt; 0 outside the window). ``times``: [N+1] the states' times, if not
        t0 + k·dt (e.g. a closed-loop run sampled otherwise)."""
        times = self._times(N, t0, times)
        active = np.zeros((len(self.terms), N + 1), bool)
        factor = np.zeros((len(self.terms), N + 1))
        scale = self.dt if self.running_cost_dt else 1.0
        for i, t in enumerate(self.terms):
            active[i], factor[i] = t.time.factors(times, scale, self.end_time)
        return active, factor

    def _times(self, N: int, t0: float, times=None) -> np.ndarray:
        if times is not None and len(times) == N + 1:
            return np.asarray(times, float)
        return t0 + self.dt * np.arange(N + 1)

    def _evaluate(self, X: np.ndarray, t0: float, jac: bool, times=None, unweighted=False):
        """Per term: residuals R [N+1, m] (0 outside its window), Jacobians [N+1, m, nx] (with
        ``jac``) and the measured quantity at each active step (dict k -> value). Terms of
        weight 0 (e.g. an approach term that only a continuation stage switches on) cost
        nothing and are left out (their R stays 0) unless ``unweighted``: a report measures
        them."""
        X = np.asarray(X, float)
        N = X.shape[0] - 1
        active, factor = self.windows(N, t0, times)
        if not unweighted:
            active = active & self._weighted
        R = [np.zeros((N + 1, t.size)) for t in self.terms]
        Js = [np.zeros((N + 1, t.size, self.nx)) for t in self.terms] if jac else None
        meas: list[dict] = [{} for _ in self.terms]
        times = self._times(N, t0, times)
        for k in np.flatnonzero(active.any(axis=0)):
            self.kin.set(X[k])
            for i in np.flatnonzero(active[:, k]):
                t = self.terms[i]
                need = jac and factor[i, k] > 0
                r, J, m = t.evaluate(self.kin, X[k], float(times[k]), need)
                R[i][k] = r
                if need:
                    Js[i][k] = J
                meas[i][int(k)] = m
        return active, factor, R, Js, meas

    def stage_costs(self, X: np.ndarray, t0: float = 0.0) -> np.ndarray:
        """The terms' cost at each step: [N+1]."""
        return np.sum(self._costs(X, t0), axis=0)

    def _costs(self, X, t0) -> np.ndarray:
        """[n_terms, N+1]."""
        active, factor, R, _, _ = self._evaluate(X, t0, False)
        out = np.empty((len(self.terms), X.shape[0]))
        with np.errstate(over="ignore", invalid="ignore"):
            for i, t in enumerate(self.terms):
                c = t.quadratic.costs(factor[i], R[i])
                out[i] = t.aggregate.spread(c, active[i] & (factor[i] > 0))
        return out

    def breakdown(self, X: np.ndarray, t0: float = 0.0) -> dict[str, float]:
        """``terms.<name>`` -> the term's cost along X."""
        c = self._costs(X, t0)
        return {f"terms.{t.name}": float(np.sum(c[i])) for i, t in enumerate(self.terms)}

    def quadratize(self, X: np.ndarray, t0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Gauss-Newton lx: [N+1, nx] and lxx: [N+1, nx, nx] of the terms along X."""
        active, factor, R, Js, _ = self._evaluate(X, t0, True)
        n = X.shape[0]
        lx, lxx = np.zeros((n, self.nx)), np.zeros((n, self.nx, self.nx))
        for i, t in enumerate(self.terms):
            f = factor[i][:, None]
            p = t.aggregate.step_weights(
                lambda i=i, t=t: t.quadratic.costs(factor[i], R[i]), active[i] & (factor[i] > 0)
            )
            if p is not None:  # d(soft minimum)/dc_k = p_k: each step's own terms times p_k
                f = f * p[:, None]
            lx += t.quadratic.gradient(f, Js[i], R[i])
            lxx += t.quadratic.hessian(f, Js[i])
        return lx, lxx

    def report(self, X: np.ndarray, t0: float = 0.0, times=None) -> dict[str, dict]:
        """Per term, at the last step of its window in X: ``error`` (|r|, unweighted: m, m/s),
        ``final`` (the point's position or velocity [3], the height or distance), ``step``;
        and ``cost`` (its cost along X). A soft minimum's at the step where its cost is
        smallest. Empty for a term whose window holds no step. ``times``: [N+1] the states'
        times, if not t0 + k·dt."""
        active, factor, R, _, meas = self._evaluate(X, t0, False, times, unweighted=True)
        out = {}
        for i, t in enumerate(self.terms):
            steps = np.flatnonzero(active[i])
            if steps.size == 0:
                continue
            c = t.quadratic.costs(factor[i], R[i])
            cost, k = t.aggregate.total(c, active[i] & (factor[i] > 0), steps)
            m = meas[i][k]
            out[t.name] = {
                "error": float(np.linalg.norm(R[i][k])),
                "final": np.asarray(m, float).tolist() if np.ndim(m) else float(m),
                "step": k,
                "cost": cost,
            }
        return out
