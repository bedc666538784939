"""Metric ``flight``: did a legged robot leave the ground, and how far did its base go.

``metric_params``: ``foot`` (a body, collision name or ``BODY/COLLISION``: the geometry that
carries the robot; several: a list) and ``base`` (the body whose travel counts). From the
contact timeline (``contacts``: the states in which any of the foot geometries touches
anything) and the base body's position in every state:

- ``flight_phases``: runs of states without foot contact that start after a state with it
  (the robot took off; a run at the start, before any contact, does not count);
- ``flight_time_s``: their total length, ``longest_flight_s`` the longest (a run of n states
  lasts n time steps);
- ``base_displacement_m``: [dx, dy, dz] of the base body's origin from the first to the last
  state (world frame), and ``base_forward_m`` its x;
- ``base_lowest_m``: the lowest height (world z) of the base body's origin over all states:
  a robot that fell or folded its leg on the way has a low one, whatever its travel.

A goal can ask for a hop that stays upright: ``flight_phases: {min: 1}``, ``base_forward_m:
{min: 0.4}``, ``base_lowest_m: {min: 0.3}``.
"""

from __future__ import annotations

import numpy as np

from hydroilqr.metrics.contacts import _cached, state_step
from hydroilqr.metrics.registry import Metric, register
from hydroilqr.model.contacts import runs
from hydroilqr.model.names import find_body
from hydroilqr.problem.errors import ConfigError


def _feet(task) -> list[str]:
    foot = task.config.metric_params.get("foot")
    return [foot] if isinstance(foot, str) else list(foot or [])


def _matches(name: str, body: str, feet: list[str]) -> bool:
    return name in feet or body in feet or f"{body}/{name}" in feet


def flight_metrics(task, sol) -> dict:
    pairs, on, _ = _cached(task, sol)
    feet = _feet(task)
    cols = [
        j
        for j, (names, bodies) in enumerate(pairs)
        if any(_matches(n, b, feet) for n, b in zip(names, bodies))
    ]
    touching = on[:, cols].any(axis=1) if cols else np.zeros(len(on), bool)
    dt = state_step(task, sol)
    first = int(np.argmax(touching)) if touching.any() else len(touching)
    flights = [(a, b) for a, b in runs(~touching) if a > first]
    lengths = [(b - a + 1) * dt for a, b in flights]
    plant = task.dynamics.plant
    body = find_body(plant, task.config.metric_params["base"], "metric_params.base")
    ctx = task.dynamics.plant_context

    def position(x):
        plant.SetPositionsAndVelocities(ctx, x)
        return np.asarray(plant.EvalBodyPoseInWorld(ctx, body).translation())

    d = position(sol.X[-1]) - position(sol.X[0])
    lowest = min(float(position(x)[2]) for x in sol.X)
    return {
        "flight_phases": len(flights),
        "flight_time_s": float(sum(lengths)),
        "longest_flight_s": float(max(lengths, default=0.0)),
        "base_displacement_m": d.tolist(),
        "base_forward_m": float(d[0]),
        "base_lowest_m": lowest,
    }


def validate_flight(task) -> None:
    params = task.config.metric_params
    if not _feet(task) or not isinstance(params.get("base"), str):
        raise ConfigError(
            "metric_params: the flight metric needs foot (collision names or bodies) and base "
            "(a body name)"
        )
    find_body(task.dynamics.plant, params["base"], "metric_params.base")
    names = task.dynamics.geometry_names().values()
    for f in _feet(task):
        if not any(_matches(n, b, [f]) for n, b in names):
            known = sorted({n for n, _ in names} | {b for _, b in names})
            raise ConfigError(
                f"metric_params.foot: no collision geometry or body {f!r} "
                f"(known: {', '.join(known)})"
            )


register(
    Metric(
        "flight",
        compute=flight_metrics,
        validate=validate_flight,
        headline=(
            ("forward m", "base_forward_m", ".3f", 1.0),
            ("flights", "flight_phases", "d", 1.0),
            ("longest flight s", "longest_flight_s", ".2f", 1.0),
            ("lowest base m", "base_lowest_m", ".3f", 1.0),
        ),
    )
)
