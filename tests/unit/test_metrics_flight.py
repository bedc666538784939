"""The flight metric (metrics/flight.py) on a made-up contact timeline: runs without foot
contact after a first contact count as flights; the base's travel from first to last state."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hydroilqr import Task
from hydroilqr.metrics import flight, validate_task
from hydroilqr.problem.errors import ConfigError


def test_flights_are_the_runs_without_foot_contact_after_the_first_contact(monkeypatch):
    task = Task.load("hopper-forward", ["num_steps=8"])
    on = np.array([0, 1, 1, 0, 0, 1, 0, 1, 1], bool)[:, None]  # 9 states
    pairs = [(("foot", "ground"), ("shin", "world"))]
    monkeypatch.setattr(flight, "_cached", lambda task, sol: (pairs, on, np.zeros(on.shape)))
    X = np.tile(task.x0, (9, 1))
    X[-1, task.dynamics.layout.block("base_x").coords[0]] += 0.3
    z = task.dynamics.layout.block("base_z").coords[0]
    X[4, z] -= 0.25  # the torso dips 0.25 m at one state
    m = flight.flight_metrics(task, SimpleNamespace(X=X, U=None, t=np.arange(9) * 0.05))
    # state 0 (before any contact) is not a flight; 3-4 and 6 are
    assert m["flight_phases"] == 2
    assert m["flight_time_s"] == pytest.approx(0.15)
    assert m["longest_flight_s"] == pytest.approx(0.10)
    assert m["base_forward_m"] == pytest.approx(0.3)
    assert m["base_displacement_m"] == pytest.approx([0.3, 0.0, 0.0])
    z0 = flight.flight_metrics(task, SimpleNamespace(X=X[:1], U=None, t=np.zeros(1)))
    assert m["base_lowest_m"] == pytest.approx(z0["base_lowest_m"] - 0.25)


def test_the_flight_metric_needs_a_foot_and_a_base():
    with pytest.raises(ConfigError, match="needs foot"):
        validate_task(Task.load("hopper-forward", ["num_steps=8", "metric_params={base: torso}"]))
    with pytest.raises(ConfigError, match="no body named .nothing. .known: world"):
        validate_task(Task.load("hopper-forward", ["num_steps=8", "metric_params.base=nothing"]))
    with pytest.raises(ConfigError, match="no collision geometry"):
        validate_task(Task.load("hopper-forward", ["num_steps=8", "metric_params.foot=hand"]))


def test_flight_lengths_use_the_states_own_spacing(monkeypatch):
    """A closed-loop run on a robot stepping finer than the plan (``mpc --plant-time-step``):
    lengths count its steps, not the task's plan step."""
    task = Task.load("hopper-forward", ["num_steps=8"])
    on = np.array([0, 1, 1, 0, 0, 1, 0, 1, 1], bool)[:, None]
    pairs = [(("foot", "ground"), ("shin", "world"))]
    monkeypatch.setattr(flight, "_cached", lambda task, sol: (pairs, on, np.zeros(on.shape)))
    X = np.tile(task.x0, (9, 1))
    m = flight.flight_metrics(task, SimpleNamespace(X=X, U=None, t=np.arange(9) * 0.01))
    assert m["flight_time_s"] == pytest.approx(0.03)
    assert m["longest_flight_s"] == pytest.approx(0.02)
