"""The task as a whole (``TaskConfig``): the plant part (problem/plant.py) and every other
section of a task file, with the checks of its own top-level keys (name, horizon, num_steps).
docs/task-format.md describes the format, ``hydroilqr schema`` generates its JSON Schema."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from hydroilqr.problem.checks import MAX_STEPS
from hydroilqr.problem.cost import CostConfig, has_cost_terms
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.goal import GoalCheck
from hydroilqr.problem.guess import PositionGuess
from hydroilqr.problem.mpc import MPCConfig
from hydroilqr.problem.plant import PlantSpec
from hydroilqr.problem.receding import RecedingHorizonConfig
from hydroilqr.problem.search import SearchConfig
from hydroilqr.problem.solver import SolverConfig


@dataclass
class TaskConfig(PlantSpec):
    """A task file's content, typed (the plant part's fields come from ``PlantSpec``)."""

    description: str = ""
    horizon: float = 1.0
    num_steps: int = 0  # if > 0, overrides horizon
    # zeros | gravity_compensation | hold | a file, or a path of configurations (PositionGuess)
    initial_guess: str | PositionGuess = "zeros"
    cost: CostConfig = field(default_factory=CostConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    receding_horizon: RecedingHorizonConfig | None = None
    mpc: MPCConfig = field(default_factory=MPCConfig)
    metrics: list[str] = field(default_factory=lambda: ["default"])
    metric_params: dict[str, Any] = field(default_factory=dict)
    # What success means in the physical world: bounds on the run's metrics (see
    # hydroilqr.metrics.goals), e.g. {target_error_m: {max: 0.03}}.
    goal: dict[str, GoalCheck] = field(default_factory=dict)
    # Continuation (homotopy) for single solves: first solve the task with each stage's dotted
    # overrides (e.g. a softer contact), each stage warm-starting the next with its controls,
    # then the task as written. Softer contact has smoother gradients (paper §IV-C).
    continuation: list[dict[str, Any]] = field(default_factory=list)
    # Robust (ensemble) iLQR for single solves: perturbed copies of the task, each a mapping of
    # dotted overrides (e.g. {ball.friction: 0.14}); one control sequence is optimized against
    # the task itself (the nominal) and every member at once (model/ensemble.py). Empty: off.
    ensemble: list[dict[str, Any]] = field(default_factory=list)
    # The cost weight of each perturbed member relative to the nominal's 1 (>= 0).
    ensemble_weight: float = 1.0
    # Solve the task alone first (from its initial guess) and start the ensemble solve from
    # that plan; false: the ensemble solve starts from the initial guess itself.
    ensemble_warm_start: bool = True
    # Named model errors to check a plan against: each a mapping of dotted overrides of the
    # "real" system in playback (the keys --truth-set takes), e.g. {friction-30: {ball.friction:
    # 0.14}}; `playback --mismatch NAME` applies one, the results page plays back every one.
    mismatch: dict[str, dict[str, Any]] = field(default_factory=dict)
    # A sampling search before iLQR (SearchConfig); none: iLQR from the initial guess alone.
    search: SearchConfig | None = None
    # Dotted overrides applied by --smoke (a tiny version of the task for tests and quick tries).
    smoke: dict[str, Any] = field(default_factory=dict)
    # Set by the loader: the task was shrunk by --smoke (its goal is the full task's).
    smoke_run: bool = field(default=False, metadata={"task_file": False})

    @property
    def steps(self) -> int:
        if self.num_steps > 0:
            return int(self.num_steps)
        return max(1, int(round(self.horizon / self.plant.time_step)))

    def to_dict(self) -> dict[str, Any]:
        """The resolved task as plain data (a task file with the same content solves it: the
        trajectory length is given once, as num_steps when set, else as horizon)."""
        d = dataclasses.asdict(self)
        d.pop("base_dir", None)
        d.pop("smoke_run", None)
        d.pop("virtual_forces", None)  # (a realization's own plant: not a task-file key)
        d["mpc"].pop("pushes", None)  # not a task-file key
        if d.get("num_steps"):
            d.pop("horizon", None)
        return {"name": d.pop("name"), "description": d.pop("description"), **d}


def validate_task(cfg: TaskConfig) -> None:
    """The task's own keys: its name (a directory name) and its length (a positive horizon of
    whole time steps, or num_steps; at most MAX_STEPS); the plant's time step is checked."""
    if not all(c.isalnum() or c in "-_.@+" for c in cfg.name) or cfg.name.startswith("."):
        raise ConfigError(
            f"name: {cfg.name!r} is used as a directory name (runs/NAME): letters, digits "
            "and - _ . @ + only"
        )
    if cfg.horizon <= 0 and cfg.num_steps <= 0:
        raise ConfigError(f"horizon: must be positive, got {cfg.horizon}")
    if cfg.num_steps < 0:
        raise ConfigError(f"num_steps: must be positive (or 0: use horizon), got {cfg.num_steps}")
    steps = cfg.horizon / cfg.plant.time_step
    if cfg.num_steps == 0 and abs(steps - round(steps)) > 1e-6 * max(1.0, steps):
        raise ConfigError(
            f"horizon: {cfg.horizon:g} s is not a whole number of time steps "
            f"({cfg.plant.time_step:g} s)"
        )
    n = cfg.num_steps or round(steps)
    if n > MAX_STEPS:  # it would not fail, it would allocate and run for ever
        what = "num_steps" if cfg.num_steps else f"horizon: {cfg.horizon:g} s is"
        raise ConfigError(f"{what} {n} time steps; at most {MAX_STEPS} (a longer time step?)")


def validate_for_solve(cfg: TaskConfig) -> None:
    """Checks a task must pass to be solved (a task that only describes a plant, e.g. for
    its dynamics, need not): ConfigError for a cost without terms."""
    if not has_cost_terms(cfg.cost):
        raise ConfigError(
            "cost: no terms (every weight in Q, Qf, R and cost.terms is zero or missing): there "
            "is nothing to optimize; give the cost some positive weights"
        )
