"""The gait report's numbers (issue 37) on gaits whose answers are known."""

import numpy as np
import pytest

from hydroilqr import Task
from hydroilqr.metrics import compute
from hydroilqr.metrics.cheetah import _phase, _strides

LABELS = ["FL", "FR", "HL", "HR"]


def _gait(offsets: list[float], duty: float = 0.5, period: float = 0.4, T: float = 2.0):
    """Contact flags [K, 4] of feet that touch down every ``period`` s at their ``offsets``
    (fractions of the period) and stay down ``duty`` of it; times [K]."""
    t = np.arange(0.0, T, 0.01)
    phase = (t[:, None] / period - np.asarray(offsets)[None, :]) % 1.0
    return t, phase < duty


@pytest.mark.parametrize(
    "offsets, diagonal, lateral",
    [
        ([0.0, 0.5, 0.5, 0.0], 0.0, 0.5),  # trot: FL+HR together, FR+HL half a stride later
        ([0.0, 0.5, 0.0, 0.5], 0.5, 0.0),  # pace: same-side feet together
        ([0.0, 0.25, 0.5, 0.75], 0.25, 0.5),  # walk (lateral sequence)
    ],
)
def test_pair_phase_and_stride_frequency_of_known_gaits(offsets, diagonal, lateral):
    t, f = _gait(offsets)
    s = _strides(t, f, t, LABELS)
    assert s["pair_phase"]["diagonal"] == pytest.approx(diagonal, abs=0.03)
    assert s["pair_phase"]["lateral"] == pytest.approx(lateral, abs=0.03)
    for foot in LABELS:  # a touchdown every 0.4 s
        assert s["stride_frequency_hz"][foot] == pytest.approx(2.5, abs=0.3)


def test_phase_needs_two_touchdowns():
    assert _phase(np.array([0.1]), np.array([0.2])) is None
    assert _phase(np.array([0.1, 0.5]), np.array([])) is None
    assert _phase(np.array([0.0, 1.0]), np.array([0.9])) == pytest.approx(0.1)  # folded


def test_gait_report_on_a_cheetah_rollout():
    """Every number of the report is there and finite on a short rollout of the guess; the
    cost of transport is the actuators' absolute work over m·g·distance (None when the base
    does not move forward)."""
    task = Task.load("cheetah-trot-1.0", smoke=True)
    U = task.initial_guess(task.steps)
    X = task.dynamics.rollout(task.x0, U)
    t = task.dynamics.dt * np.arange(len(X))
    m = compute(task, type("Sol", (), {"t": t, "X": X, "U": U, "extra": {}, "costs": [0.0]})())
    assert set(m["stance_slip_mps"]) == set(LABELS) and m["mean_stance_slip_mps"] >= 0.0
    assert set(m["stride_frequency_hz"]) == set(LABELS)
    assert set(m["pair_phase"]) == {"diagonal", "lateral"}
    cot = m["cost_of_transport"]
    assert cot is None or (np.isfinite(cot) and cot > 0)
