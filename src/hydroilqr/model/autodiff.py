"""AutoDiff partials of the plant's discrete step, one time step after another in one process
(the paper's method); ``derivatives`` and the worker processes (``workers``) both run it."""

from __future__ import annotations

import numpy as np
from pydrake.autodiffutils import ExtractGradient, InitializeAutoDiff

from hydroilqr.model.plant import Dynamics, SimulationError


def autodiff_serial(dyn: Dynamics, X: np.ndarray, U: np.ndarray):
    """AutoDiff partials one time step after another in this process (the paper's method).
    X: [N, nx], U: [N, nu] -> A: [N, nx, nx], B: [N, nx, nu]."""
    _, ad_context, ad_plant, ad_plant_context, ad_input = dyn.autodiff()
    N, nx, nu = U.shape[0], dyn.nx, dyn.nu
    A = np.empty((N, nx, nx))
    B = np.empty((N, nx, nu))
    for k in range(N):
        z = InitializeAutoDiff(np.concatenate([X[k], U[k]]))
        ad_plant.SetPositionsAndVelocities(ad_plant_context, z[:nx])
        ad_input.FixValue(ad_context, z[nx:])
        try:
            xn = ad_plant.EvalUniquePeriodicDiscreteUpdate(ad_plant_context).value(0)
        except RuntimeError as e:
            raise SimulationError(f"autodiff step {k}: {str(e).strip().splitlines()[0]}") from None
        G = ExtractGradient(xn)
        if G.shape[1] != nx + nu:  # no dependence at all (cannot happen for a real plant)
            G = np.zeros((nx, nx + nu))
        A[k], B[k] = G[:, :nx], G[:, nx:]
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(B))):
        raise SimulationError("non-finite autodiff derivatives")
    return A, B
