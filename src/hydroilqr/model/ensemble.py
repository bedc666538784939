"""Robust (ensemble) iLQR: one control sequence optimized against M models at once.

The members are a nominal model (first) and perturbed copies of it (another friction, mass,
contact stiffness, ...), each with its own state of size n. The ensemble is one system whose
state stacks theirs, all driven by the same input u:

    x = [x_1; ...; x_M]          (nx = M·n)
    f(x, u) = [f_1(x_1, u); ...; f_M(x_M, u)]

so its partials are block diagonal in the state and stacked in the input,

    A_k = diag(A_1k, ..., A_Mk)  [M·n, M·n],   B_k = [B_1k; ...; B_Mk]  [M·n, nu],

and its cost is the weighted sum of the members' costs (nominal weight 1, each perturbed
member w = ``ensemble_weight``),

    J(X, U) = Σ_m w_m J_m(X_m, U)

(so the control term uᵀRu counts Σ_m w_m times). Its quadratization stacks l_x and l_xx
block-diagonally and sums l_u, l_uu with the weights. The forward pass of iLQR (eq. 7) acts on
the stacked state, u_k = ū_k − ε κ_k − K_k (x_k − x̄_k), every member stepped with that u_k:
K_k: [nu, M·n] feeds back every member's deviation. Each member's rollout and partials are
independent of the others'; a trial or an iteration costs M rollouts and M linearizations.

These classes are duck-typed stand-ins for ``plant.Dynamics``, ``derivatives.Linearizer``
and ``cost.QuadraticCost`` as ``solver.loop.solve`` uses them. The ensemble dynamics has no
``spec``: its line search runs serially (no worker pool).
"""

from __future__ import annotations

import numpy as np

from hydroilqr.model.cost import QuadraticCost, Quadratization
from hydroilqr.model.derivatives import Linearizer
from hydroilqr.model.plant import Dynamics, SimulationError, feedback_rollout


def _blocks(M: int, n: int) -> list[slice]:
    """The slices of the M members' coordinates in a stacked vector of size M·n."""
    return [slice(m * n, (m + 1) * n) for m in range(M)]


class EnsembleDynamics:
    """The stacked dynamics of ``members`` (nominal first; every member has the same state
    size n and input size nu). Attributes: ``n`` (a member's state size), ``M``,
    ``nx = M·n``, ``nu``, ``dt`` (the nominal's), ``blocks`` (each member's slice of x)."""

    def __init__(self, members: list[Dynamics]):
        if not members:
            raise ValueError("EnsembleDynamics: at least one member")
        nominal = members[0]
        for i, d in enumerate(members):
            if (d.nx, d.nu) != (nominal.nx, nominal.nu) or d.dt != nominal.dt:
                raise ValueError(
                    f"ensemble member {i}: nx {d.nx}, nu {d.nu}, dt {d.dt:g} differ from the "
                    f"nominal's {nominal.nx}, {nominal.nu}, {nominal.dt:g}"
                )
        self.members = list(members)
        self.M = len(members)
        self.n = nominal.nx
        self.nx = self.M * self.n
        self.nu = nominal.nu
        self.dt = nominal.dt
        self.blocks = _blocks(self.M, self.n)

    def stack(self, x: np.ndarray) -> np.ndarray:
        """x: [n] (one state for every member) -> [M·n]."""
        return np.tile(np.asarray(x, dtype=float), self.M)

    def check_arguments(self, X, U, x_rows: bool = False, u_rows: bool = False):
        """As ``Dynamics.check_arguments``, for stacked states X: [M·n] (or [rows, M·n])."""
        X, U = np.asarray(X, dtype=float), np.asarray(U, dtype=float)
        if X.ndim != 1 + x_rows or X.shape[-1] != self.nx:
            raise ValueError(f"state x must have shape [..., {self.nx}] (M·n), got {X.shape}")
        if U.ndim != 1 + u_rows or U.shape[-1] != self.nu:
            raise ValueError(f"input u must have shape [..., {self.nu}] (nu), got {U.shape}")
        if not (np.isfinite(X).all() and np.isfinite(U).all()):
            raise SimulationError("non-finite (NaN or infinite) state or input")
        return X, U

    def _step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Every member stepped with u; SimulationError naming the member that failed."""
        xn = np.empty(self.nx)
        for m, (d, b) in enumerate(zip(self.members, self.blocks)):
            try:
                xn[b] = d._step(x[b], u)
            except SimulationError as e:
                raise SimulationError(f"ensemble member {m}: {e}") from None
        return xn

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """x: [M·n], u: [nu] -> [M·n]."""
        return self._step(*self.check_arguments(x, np.atleast_1d(u)))

    def rollout(self, x0: np.ndarray, U: np.ndarray) -> np.ndarray:
        """Open loop: x0: [M·n], U: [N, nu] -> X: [N+1, M·n] (each member's own rollout)."""
        x0, U = self.check_arguments(x0, U, u_rows=True)
        X = np.empty((U.shape[0] + 1, self.nx))
        for m, (d, b) in enumerate(zip(self.members, self.blocks)):
            try:
                X[:, b] = d.rollout(x0[b], U)
            except SimulationError as e:
                raise SimulationError(f"ensemble member {m}: {e}") from None
        return X

    def closed_loop_rollout(self, x0, Ubar, Xbar, K, kappa, eps):
        """Forward pass (eq. 7) on the stacked state: u_k = ū_k − ε κ_k − K_k (x_k − x̄_k),
        every member stepped with u_k. x0: [M·n], Ubar: [N, nu], Xbar: [N+1, M·n],
        K: [N, nu, M·n], kappa: [N, nu] -> X: [N+1, M·n], U: [N, nu]."""
        x0, Ubar = self.check_arguments(x0, Ubar, u_rows=True)
        return feedback_rollout(self._step, x0, Ubar, Xbar, K, kappa, eps)

    def member_states(self, X: np.ndarray, m: int) -> np.ndarray:
        """Member m's states of stacked X: [..., M·n] -> [..., n]."""
        return X[..., self.blocks[m]]


class EnsembleLinearizer:
    """Partials of the stacked dynamics from one ``Linearizer`` per member (same order as
    ``EnsembleDynamics.members``): A: [N, M·n, M·n] block diagonal, B: [N, M·n, nu].
    ``last_computed``: the steps the members differentiated in the last call, summed;
    ``last_secant``: some of the last call's partials were secant updates (members fall out
    of step when one's update is not finite or one's exact call fails): then they are not
    exact, and the solver's ``exact`` recomputes them all."""

    def __init__(self, member_linearizers: list[Linearizer]):
        self.members = list(member_linearizers)
        self.last_computed = 0
        self.last_secant = False

    @staticmethod
    def from_settings(dynamics: EnsembleDynamics, s) -> EnsembleLinearizer:
        """One ``Linearizer.from_settings`` per member of ``dynamics``."""
        return EnsembleLinearizer([Linearizer.from_settings(d, s) for d in dynamics.members])

    def _stack(self, X: np.ndarray, U: np.ndarray, call) -> tuple[np.ndarray, np.ndarray]:
        """A, B from ``call(member_linearizer, X_m)`` for each member's states X_m."""
        n = X.shape[1] // len(self.members)
        N, nu = U.shape
        M = len(self.members)
        A = np.zeros((N, M * n, M * n))
        B = np.empty((N, M * n, nu))
        for b, lin in zip(_blocks(M, n), self.members):
            A[:, b, b], B[:, b, :] = call(lin, X[:, b])
        self.last_computed = sum(lin.last_computed for lin in self.members)
        self.last_secant = any(getattr(lin, "last_secant", False) for lin in self.members)
        return A, B

    def __call__(self, X: np.ndarray, U: np.ndarray, rollout: bool = False):
        """X: [N+1, M·n], U: [N, nu] -> A: [N, M·n, M·n], B: [N, M·n, nu]."""
        return self._stack(X, U, lambda lin, Xm: lin(Xm, U, rollout=rollout))

    def exact(self, X: np.ndarray, U: np.ndarray, rollout: bool = False):
        """As a call, with every member's exact partials (``Linearizer.exact``)."""
        return self._stack(X, U, lambda lin, Xm: lin.exact(Xm, U, rollout=rollout))


class EnsembleCost:
    """J(X, U) = Σ_m w_m J_m(X_m, U) over the members' costs (nominal first, its weight 1 by
    convention); X: [N+1, M·n], U: [N, nu]."""

    def __init__(self, member_costs: list[QuadraticCost], weights):
        self.members = list(member_costs)
        self.weights = np.asarray(weights, dtype=float)
        if self.weights.shape != (len(self.members),):
            raise ValueError("EnsembleCost: one weight per member")
        self.n = self.members[0].layout.nx
        self.blocks = _blocks(len(self.members), self.n)
        self.dt = self.members[0].dt

    def times(self, N: int, t0: float) -> np.ndarray:
        """The nominal's time grid: [N+1]."""
        return self.members[0].times(N, t0)

    def _each(self, X, U, t0, what: str):
        """(w_m, member m's ``what``(X_m, U, t0)) for every member."""
        for w, c, b in zip(self.weights, self.members, self.blocks):
            yield w, getattr(c, what)(X[:, b], U, t0)

    def stage_costs(self, X: np.ndarray, U: np.ndarray, t0: float = 0.0) -> np.ndarray:
        """Σ_m w_m (member m's cost per step): [N+1] (the last entry is terminal)."""
        with np.errstate(over="ignore", invalid="ignore"):
            return sum(w * c for w, c in self._each(X, U, t0, "stage_costs"))

    def total(self, X: np.ndarray, U: np.ndarray, t0: float = 0.0) -> float:
        """Σ_m w_m J_m(X_m, U)."""
        with np.errstate(over="ignore", invalid="ignore"):
            return float(np.sum(self.stage_costs(X, U, t0)))

    def breakdown(self, X: np.ndarray, U: np.ndarray, t0: float = 0.0) -> dict[str, float]:
        """Each named term (Q.<block>, Qf.<block>, R) summed over the members with weights."""
        out: dict[str, float] = {}
        for w, terms in self._each(X, U, t0, "breakdown"):
            for name, v in terms.items():
                out[name] = out.get(name, 0.0) + float(w * v)
        return out

    def quadratize(self, X: np.ndarray, U: np.ndarray, t0: float = 0.0) -> Quadratization:
        """lx: [N+1, M·n] and lxx: [N+1, M·n, M·n] stacked block by block (times w_m);
        lu: [N, nu], luu: [N, nu, nu] summed with the weights."""
        N, nu = U.shape
        nx = X.shape[1]
        lx, lxx = np.zeros((N + 1, nx)), np.zeros((N + 1, nx, nx))
        lu, luu = np.zeros((N, nu)), np.zeros((N, nu, nu))
        for b, (w, q) in zip(self.blocks, self._each(X, U, t0, "quadratize")):
            lx[:, b] = w * q.lx
            lxx[:, b, b] = w * q.lxx
            lu += w * q.lu
            luu += w * q.luu
        return Quadratization(lx, lxx, lu, luu)
