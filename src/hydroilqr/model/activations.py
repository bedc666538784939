"""Activations of the task-space cost terms (model/terms.py): small objects composed with a
residual (model/residuals.py), as crocoddyl composes its residual models with activations.

Per step, a term's residual r (or measured s) is shaped, then squared:

* ``Identity``: r itself; ``Target``: ``r = s − target``; ``Bounds``: the part of s beyond
  [lower, upper], ``r = min(0, s − lower) + max(0, s − upper)`` (a one-sided barrier:
  ∂r/∂s is 1 outside the bounds, 0 inside), per component.
* ``Quadratic``: the step's cost ``f_k · Σ_i w_i r_i²`` (f_k: the time shaping's factor,
  model/windows.py; no ½, the convention of ``cost.py``), with the Gauss-Newton derivatives
  ``l_x = 2 f Jᵀ W r`` and ``l_xx = 2 f Jᵀ W J``.

Over the steps of its window, the costs c_k are summed (``Sum``), or a running term with
``softmin`` τ > 0 costs their soft minimum (``SoftMin``), ``S = −τ log(mean_k exp(−c_k/τ))``
(between their minimum and their mean): a small residual at some step, not at every one.
``∂S/∂c_k = p_k``, the softmax of −c_k/τ, so each step's derivatives are scaled by p_k (the
coupling between steps is dropped from the Hessian: it is negative semidefinite, and the rest
stays positive semidefinite).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Identity:
    """r as the residual gives it."""

    def __call__(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(r, ∂r/∂s per component, None: 1 everywhere)."""
        return s, None


@dataclass(frozen=True)
class Target:
    """r = s − target."""

    target: float

    def __call__(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        return s - self.target, None


@dataclass(frozen=True)
class Bounds:
    """r = min(0, s − lower) + max(0, s − upper): 0 inside the bounds (numbers or one per
    component; ±inf: no bound on that side)."""

    lower: float | np.ndarray
    upper: float | np.ndarray

    def __call__(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        r = np.minimum(0.0, s - self.lower) + np.maximum(0.0, s - self.upper)
        return r, (r != 0.0).astype(float)


@dataclass(frozen=True)
class Quadratic:
    """A step's cost f_k Σ_i w_i r_i² (``weights`` [m]) and its Gauss-Newton derivatives."""

    weights: np.ndarray

    def costs(self, factor: np.ndarray, R: np.ndarray) -> np.ndarray:
        """Each step's cost: [N+1] (factor [N+1], R [N+1, m])."""
        return factor * np.einsum("ki,i,ki->k", R, self.weights, R)

    def gradient(self, f: np.ndarray, J: np.ndarray, R: np.ndarray) -> np.ndarray:
        """2 f Jᵀ W r: [N+1, nx] (f [N+1, 1], J [N+1, m, nx])."""
        return 2.0 * f * np.einsum("kmj,m,km->kj", J, self.weights, R)

    def hessian(self, f: np.ndarray, J: np.ndarray) -> np.ndarray:
        """2 f Jᵀ W J: [N+1, nx, nx]."""
        return 2.0 * f[:, :, None] * np.einsum("kmj,m,kml->kjl", J, self.weights, J)


@dataclass(frozen=True)
class Sum:
    """A term's cost over its window: the sum of its steps' costs."""

    def spread(self, c: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Per step, what the term adds to that step's cost: [N+1]."""
        return c

    def step_weights(self, costs, mask: np.ndarray) -> np.ndarray | None:
        """∂(term's cost)/∂c_k: [N+1], or None for 1 at every step (``costs()``: the steps'
        costs c [N+1], computed only when needed)."""
        return None

    def total(self, c: np.ndarray, mask: np.ndarray, steps: np.ndarray) -> tuple[float, int]:
        """(the term's cost, the step a report shows: the window's last)."""
        return float(np.sum(c)), int(steps[-1])


@dataclass(frozen=True)
class SoftMin:
    """A term's cost over its window: the soft minimum of its steps' costs (temperature tau).
    ``mask``: the steps of the window that count."""

    tau: float

    def spread(self, c: np.ndarray, mask: np.ndarray) -> np.ndarray:
        # the soft minimum, spread over the window's steps (an infinite one on each)
        value, p = softmin(c, mask, self.tau)
        return p * value if np.isfinite(value) else np.where(mask, value, 0.0)

    def step_weights(self, costs, mask: np.ndarray) -> np.ndarray | None:
        return softmin(costs(), mask, self.tau)[1]

    def total(self, c: np.ndarray, mask: np.ndarray, steps: np.ndarray) -> tuple[float, int]:
        """(its value, the step where the cost is smallest)."""
        return softmin(c, mask, self.tau)[0], int(steps[np.argmin(c[steps])])


def softmin(c: np.ndarray, active: np.ndarray, tau: float) -> tuple[float, np.ndarray]:
    """The soft minimum S = -τ log(mean_k exp(-c_k / τ)) of the costs c: [N+1] over the active
    steps (a bool mask [N+1]), and its gradient p = dS/dc: [N+1] (softmax weights of -c/τ on
    the active steps, summing to 1; 0 elsewhere). S lies between min and mean of the active
    c_k. (0, zeros) when no step is active; (inf or NaN, zeros) when an active c_k is (as a
    sum of the costs would be)."""
    p = np.zeros_like(c)
    idx = np.flatnonzero(active)
    if idx.size == 0:
        return 0.0, p
    ca = c[idx]
    if not np.all(np.isfinite(ca)):
        return float(np.sum(ca)), p
    m = float(np.min(ca))
    e = np.exp(-(ca - m) / tau)  # shifted by the minimum: no overflow for a small τ
    value = m - tau * np.log(np.mean(e))
    p[idx] = e / np.sum(e)
    return float(value), p
