"""Splines of a few knots over a horizon: the plans a sampling search perturbs.

A spline of K knots over [0, T] is linear in its knot values: ``basis(K, times, T, order)``
is the matrix W: [len(times), K] with values = W @ knots (knots: [K, m], one column per
actuator). Orders, as mujoco_mpc's planners interpolate:

- 0, zero-order hold: knot j holds on [j T / K, (j+1) T / K) (the last one through T);
- 1, linear: knots at K evenly spaced times from 0 to T, linear in between;
- 3, cubic: the same knot times, cubic Hermite segments with finite-difference slopes
  (centred inside, one-sided at the ends): it passes through every knot, and a knot moves
  the spline only over the two segments on either side of it and their neighbours.

One knot (K = 1) is a constant for every order. Outside [0, T] the end values hold.
"""

from __future__ import annotations

import numpy as np

ORDERS = (0, 1, 3)


def knot_times(K: int, T: float, order: int) -> np.ndarray:
    """The times of the K knots: [K] (order 0: where each held value starts)."""
    if K == 1:
        return np.zeros(1)
    if order == 0:
        return T * np.arange(K) / K
    return np.linspace(0.0, T, K)


def basis(K: int, times, T: float, order: int) -> np.ndarray:
    """W: [len(times), K], the spline's values at ``times`` (s) are W @ knots."""
    if order not in ORDERS:
        raise ValueError(f"spline order must be one of {ORDERS}, got {order!r}")
    if K < 1 or not T > 0:
        raise ValueError(f"a spline needs K >= 1 knots over a positive T, got {K}, {T}")
    t = np.clip(np.asarray(times, float), 0.0, T)
    W = np.zeros((len(t), K))
    if K == 1:
        W[:, 0] = 1.0
        return W
    if order == 0:
        j = np.minimum((t * K / T + 1e-9).astype(int), K - 1)
        W[np.arange(len(t)), j] = 1.0
        return W
    h = T / (K - 1)
    s = t / h
    j = np.minimum(s.astype(int), K - 2)  # segment [t_j, t_j+1]
    u = s - j
    rows = np.arange(len(t))
    if order == 1:
        W[rows, j] = 1.0 - u
        W[rows, j + 1] = u
        return W
    # cubic Hermite: p = h00 p_j + h10 h m_j + h01 p_j+1 + h11 h m_j+1, m = D @ knots
    h00, h10 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u
    h01, h11 = -2 * u**3 + 3 * u**2, u**3 - u**2
    D = _slopes(K)  # [K, K]: h·m = D @ p
    W[rows, j] += h00
    W[rows, j + 1] += h01
    W += h10[:, None] * D[j] + h11[:, None] * D[j + 1]
    return W


def _slopes(K: int) -> np.ndarray:
    """D: [K, K] with h·m_j = (D @ p)_j: finite-difference slopes (times the knot spacing)."""
    D = np.zeros((K, K))
    D[0, :2] = [-1.0, 1.0]
    D[-1, -2:] = [-1.0, 1.0]
    for i in range(1, K - 1):
        D[i, i - 1], D[i, i + 1] = -0.5, 0.5
    return D


def evaluate(knots, times, T: float, order: int) -> np.ndarray:
    """The spline of ``knots``: [K, m] at ``times`` (s): [len(times), m]."""
    knots = np.asarray(knots, float)
    return basis(knots.shape[0], times, T, order) @ knots
