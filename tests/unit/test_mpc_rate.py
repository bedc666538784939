"""The achieved update rate a closed loop reports (mpc.json's achieved_rate_hz)."""

import numpy as np
import pytest

from hydroilqr.control.mpc import MPCResult
from hydroilqr.problem.mpc import MPCConfig


def _result(update_times, duration=2.0, rate=20.0):
    t = np.linspace(0.0, duration, 201)
    n = len(update_times)
    return MPCResult(
        X=np.zeros((201, 2)),
        U=np.zeros((200, 1)),
        t=t,
        update_times=list(update_times),
        solve_seconds=[0.01] * n,
        iterations=[1] * n,
        failures=0,
        wall_seconds=1.0,
        settings=MPCConfig(duration=duration, rate=rate),
    )


def test_every_slot_used_is_the_requested_rate():
    period = 1 / 20.0
    times = [period * k for k in range(1, 40)]  # slots after the first plan: 0.05 .. 1.95
    assert _result(times).stats()["achieved_rate_hz"] == pytest.approx(20.0)


def test_one_slow_update_is_not_reported_as_the_requested_rate():
    # One update started at 0.05 s and the plant ran the rest of the 2 s on one plan.
    rate = _result([0.05]).stats()["achieved_rate_hz"]
    assert rate == pytest.approx(1 / 1.95)


def test_no_update_after_the_first_plan_is_zero():
    assert _result([], duration=0.05).stats()["achieved_rate_hz"] == 0.0
