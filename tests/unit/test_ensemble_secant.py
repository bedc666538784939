"""EnsembleLinearizer.last_secant: the loop recomputes exact partials (``exact``) when the
current ones are secant; with one member's partials secant and another's exact, the stacked
partials are not exact either."""

from __future__ import annotations

import numpy as np

from hydroilqr.model.ensemble import EnsembleLinearizer


class _Member:
    def __init__(self, secant: bool):
        self.secant = secant
        self.last_secant = False
        self.last_computed = 0

    def __call__(self, X, U, rollout=False):
        self.last_secant = self.secant
        self.last_computed = 0 if self.secant else U.shape[0]
        n, nu = X.shape[1], U.shape[1]
        return np.zeros((U.shape[0], n, n)), np.zeros((U.shape[0], n, nu))


def test_mixed_secant_and_exact_members_count_as_secant():
    lin = EnsembleLinearizer([_Member(secant=False), _Member(secant=True)])
    X, U = np.zeros((4, 2 * 3)), np.zeros((3, 1))
    lin(X, U, rollout=True)
    assert lin.last_secant  # the loop then recomputes every member's partials exactly
    lin = EnsembleLinearizer([_Member(secant=False), _Member(secant=False)])
    lin(X, U, rollout=True)
    assert not lin.last_secant
