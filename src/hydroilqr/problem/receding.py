"""The ``receding_horizon:`` section: a trajectory solved window by window."""

from __future__ import annotations

from dataclasses import dataclass

from hydroilqr.problem.checks import MAX_STEPS
from hydroilqr.problem.errors import ConfigError

WARM_START_TAILS = ("last", "guess")  # receding_horizon. and mpc.warm_start_tail


@dataclass
class RecedingHorizonConfig:
    window_steps: int = 40
    shift_steps: int = 4
    resolves: int = 100
    max_iterations: int = 10  # per resolve (the first window uses solver.max_iterations)
    # The controls a shifted window lacks at its end: "last" holds the previous window's last
    # control (the paper's code), "guess" takes the task's initial guess for those steps.
    warm_start_tail: str = "last"
    # > 0: a window whose cost after max_iterations is above rescue_factor times the median of
    # the previous (up to 5) windows' costs gets up to rescue_iterations more iterations from
    # where it stopped (the better of the two is kept): a window where the motion starts to go
    # wrong gets the effort to turn it around. 0 = off (every window max_iterations).
    rescue_factor: float = 0.0
    rescue_iterations: int = 10


def validate_receding_horizon(rh: RecedingHorizonConfig | None) -> None:
    if rh is None:
        return
    if rh.window_steps < 1 or rh.shift_steps < 1 or rh.resolves < 1:
        raise ConfigError("receding_horizon: window_steps, shift_steps, resolves must be >= 1")
    if rh.shift_steps > rh.window_steps:
        raise ConfigError(
            f"receding_horizon.shift_steps: {rh.shift_steps} is more than the window's "
            f"{rh.window_steps} steps (each window keeps its first shift_steps)"
        )
    if rh.max_iterations < 1:
        raise ConfigError("receding_horizon.max_iterations: must be >= 1")
    if not (rh.rescue_factor == 0 or rh.rescue_factor > 1):
        raise ConfigError(
            f"receding_horizon.rescue_factor: 0 (off) or above 1, got {rh.rescue_factor!r}"
        )
    if rh.rescue_iterations < 1:
        raise ConfigError("receding_horizon.rescue_iterations: must be >= 1")
    if rh.warm_start_tail not in WARM_START_TAILS:
        raise ConfigError(
            f"receding_horizon.warm_start_tail: expected last or guess, got {rh.warm_start_tail!r}"
        )
    if rh.resolves * rh.shift_steps + rh.window_steps > MAX_STEPS:
        raise ConfigError(
            f"receding_horizon: {rh.resolves} resolves of {rh.shift_steps} steps are more than "
            f"{MAX_STEPS} time steps"
        )
