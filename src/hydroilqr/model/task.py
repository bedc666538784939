"""A task: model + contact scene + cost + initial state and guess, all from one YAML file.

task = Task.load("cartpole-wall")                      # built-in
task = Task.from_yaml("my_task.yaml", overrides=["solver.max_iterations=20"])
task.dynamics   # plant.Dynamics (built on first use)
task.cost       # cost.QuadraticCost
task.x0         # [nx]
task.initial_guess(N)  # [N, nu]
"""

from __future__ import annotations

import functools
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hydroilqr.model.cost import QuadraticCost
from hydroilqr.model.guess import position_guess, virtual_config
from hydroilqr.model.plant import Dynamics, SimulationError
from hydroilqr.problem import inputs
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.inputs import check_memory
from hydroilqr.problem.load import build_task, load_task, with_overrides
from hydroilqr.problem.task import TaskConfig
from hydroilqr.problem.variants import mismatch_overrides


@dataclass
class Problem:
    """An optimal control problem (4): dynamics, cost, x0, horizon start time t0."""

    dynamics: Dynamics
    cost: QuadraticCost
    x0: np.ndarray
    t0: float = 0.0


def check_finite(name: str, a: np.ndarray) -> None:
    """ValueError naming the first NaN or infinite entry of the array ``name``, if any."""
    if not np.isfinite(a).all():
        where = np.argwhere(~np.isfinite(a))[0].tolist()
        raise ValueError(
            f"{name} must be finite (no NaN or infinite entries): "
            f"{name}{where} is {a[tuple(where)]}"
        )


class Task:
    def __init__(self, config: TaskConfig):
        self.config = config
        # Tracking rollouts of a position guess, by (N, start, x): a few kept (model/guess.py)
        self.position_guesses: dict = {}

    def __repr__(self) -> str:  # no plant is built for it
        rh = self.config.receding_horizon
        what = (
            f"receding horizon: {rh.resolves} windows of {rh.window_steps} steps"
            if rh is not None
            else f"{self.config.steps} steps"
        )
        return f"Task({self.name!r}, {what} of {self.config.plant.time_step:g} s)"

    # ------------------------------------------------------------------ constructors
    @classmethod
    def load(
        cls, name_or_path: str, overrides=None, config_file: str | None = None, smoke: bool = False
    ) -> Task:
        """A built-in task by name, or a task YAML file by path."""
        return cls(load_task(name_or_path, overrides, config_file, smoke))

    @classmethod
    def from_yaml(
        cls, path: str | Path, overrides=None, config_file: str | None = None, smoke: bool = False
    ) -> Task:
        """A task YAML file (same as ``load`` given a path)."""
        return cls(load_task(str(path), overrides, config_file, smoke))

    @classmethod
    def from_dict(
        cls, data: dict, base_dir: str | Path = ".", overrides=None, smoke: bool = False
    ) -> Task:
        """A task from its YAML data as a dict (e.g. ``yaml.safe_load(text)``); relative paths
        in it are relative to ``base_dir``."""
        return cls(build_task(data, base_dir, overrides, None, smoke))

    def stages(self) -> list[Task]:
        """The continuation stages (``continuation:``) as Tasks, in order; the last stage is
        followed by this task itself. Built once (each holds its own plant)."""
        if getattr(self, "_stages", None) is None:
            why = "between stages (every stage solves the task's time grid from its initial state)"
            self._stages = self._variants("continuation", why)
        return self._stages

    def members(self) -> list[Task]:
        """The perturbed members of a robust solve (``ensemble:``) as Tasks, in order; the
        task itself is the nominal, not among them. Built once (each holds its own plant)."""
        if getattr(self, "_members", None) is None:
            why = "in an ensemble member (every member shares the task's time grid and start)"
            self._members = self._variants("ensemble", why)
        return self._members

    def _variants(self, section: str, why: str) -> list[Task]:
        """This task with each of ``section``'s override mappings applied (continuation
        stages or ensemble members), none of which may change the time grid or the start."""
        out = []
        cfg = self.config
        for i, overrides in enumerate(getattr(cfg, section)):
            try:
                # paths in them are relative to the task file, like the rest of it
                st = with_overrides(
                    cfg, {**overrides, "continuation": [], "ensemble": []}, Path(cfg.base_dir)
                )
            except ConfigError as e:
                raise ConfigError(f"{section}[{i}]: {e}") from None
            same = (
                st.plant.time_step == cfg.plant.time_step
                and st.steps == cfg.steps
                and st.initial_state == cfg.initial_state
                and st.initial_guess == cfg.initial_guess
            )
            if not same:  # e.g. {plant: {time_step: ...}}, which the key check cannot see
                raise ConfigError(
                    f"{section}[{i}]: the time grid, initial state and initial guess cannot "
                    f"change {why}"
                )
            out.append(Task(st))
        return out

    def virtual_task(self, weight: float = 0.0) -> Task:
        """This task on its plant with a virtual actuator on each unactuated coordinate its
        position guess names (``initial_guess.realize``; model/guess.py's ``virtual_config``),
        their R ``weight``: the realization's stages (solver/realize.py). Its guess tracks the
        path with them. Built once per weight."""
        cache = self.__dict__.setdefault("_virtual_tasks", {})
        if weight not in cache:
            r = QuadraticCost._control_weights(self.dynamics.layout, self.config.cost.R)
            cache[weight] = Task(virtual_config(self.config, self.dynamics, r, weight))
        return cache[weight]

    def with_overrides(self, overrides) -> Task:
        """A new Task with ``key=value`` overrides (a list, a dict or one string) applied.

        A Task reads its config once, when ``dynamics`` / ``cost`` / ``x0`` are first used:
        change a loaded task this way, not by editing ``task.config`` afterwards."""
        return Task(with_overrides(self.config, overrides))

    # ------------------------------------------------------------------ pieces
    @property
    def name(self) -> str:
        return self.config.name

    @functools.cached_property
    def dynamics(self) -> Dynamics:
        return Dynamics(self.config)

    @functools.cached_property
    def cost(self) -> QuadraticCost:
        return QuadraticCost.from_config(
            self.dynamics.layout,
            self.config.cost,
            self.config.plant.time_step,
            self.config.resolve_path,
            [m.file for m in self.config.models],
            dynamics=self.dynamics if self.config.cost.terms else None,
            x0=self.x0
            if self.config.cost.terms or self.config.cost.nominal_relative_to_start
            else None,
            end_time=self._end_time(),
        )

    def _end_time(self) -> float:
        """The end of the task's trajectory (s): its horizon, or a receding run's kept steps."""
        cfg, rh = self.config, self.config.receding_horizon
        steps = rh.resolves * rh.shift_steps if rh is not None else cfg.steps
        return steps * cfg.plant.time_step

    @functools.cached_property
    def x0(self) -> np.ndarray:
        return self.dynamics.initial_state()

    @property
    def steps(self) -> int:
        """Steps of one optimization window (the whole horizon unless receding)."""
        rh = self.config.receding_horizon
        return rh.window_steps if rh is not None else self.config.steps

    def validate(self, mismatch: bool = True) -> None:
        """Builds everything of the model that can fail on bad input, before any solve starts
        (``metrics.validate_task`` adds the metrics and the goal); ``mismatch=False`` skips
        building a plant per mismatch case (a sweep's jobs: checked once before them)."""
        _ = self.dynamics, self.cost, self.x0
        self.check_memory()
        self.initial_guess(self.steps)
        guess = self.config.initial_guess
        if not isinstance(guess, str) and guess.realize is not None:
            _ = self.virtual_task().dynamics  # the coordinates it realizes (model/guess.py)
        self._check_variants("continuation", self.stages())
        self._check_variants("ensemble", self.members())
        if mismatch:
            self._check_mismatch()

    def _check_mismatch(self) -> None:
        """Each mismatch case builds: its keys and files exist (the plant it changes)."""
        for name in self.config.mismatch:
            try:
                _ = Task(
                    with_overrides(self.config, mismatch_overrides(self.config, name))
                ).dynamics
            except ConfigError as e:
                raise ConfigError(f"mismatch.{name}: {e}") from None

    def _check_variants(self, section: str, tasks: list[Task]) -> None:
        """Each continuation stage or ensemble member builds, with this task's nx and nu."""
        for i, t in enumerate(tasks):
            try:
                _ = t.dynamics, t.cost
            except ConfigError as e:
                raise ConfigError(f"{section}[{i}]: {e}") from None
            if t.dynamics.nx != self.dynamics.nx or t.dynamics.nu != self.dynamics.nu:
                raise ConfigError(f"{section}[{i}]: changes the state or input size")
            if _coordinates(t.dynamics.layout) != _coordinates(self.dynamics.layout):
                raise ConfigError(
                    f"{section}[{i}]: orders or names the state's coordinates or the actuators "
                    "differently (it shares this task's initial state and controls)"
                )

    def check_memory(self, steps: int | None = None, what: str | None = None) -> None:
        """ConfigError if a solve over ``steps`` (default: this task's window or horizon, and
        a receding run's whole trajectory besides) would not fit in the memory this process
        may use (problem.inputs.available_memory)."""

        dyn, rh = self.dynamics, self.config.receding_horizon
        if steps is not None:
            check_memory(steps, dyn.nx, dyn.nu, what or "horizon")
        elif rh is None:  # an ensemble's partials are of its stacked state (M·nx)
            M = 1 + len(self.config.ensemble)
            check_memory(self.steps, M * dyn.nx, dyn.nu, "horizon")
        else:
            # the window's solve, and the kept trajectory (X, U, K, kappa) of every window
            kept = rh.resolves * rh.shift_steps
            extra = 8 * kept * (dyn.nx + 2 * dyn.nu + dyn.nu * dyn.nx)
            check_memory(rh.window_steps, dyn.nx, dyn.nu, "receding_horizon.window_steps", extra)

    def initial_guess(self, N: int, x: np.ndarray | None = None, start: int = 0) -> np.ndarray:
        """U: [N, nu] from ``initial_guess``: zeros | gravity_compensation | hold | file |
        a path of configurations (the controls of its tracking rollout, model/guess.py, from
        x at the time of step ``start``).

        x: [nx] the state the computed kinds hold (default x0). A file (``.npz`` with ``U``, or
        CSV) holds one row per time step, of which rows ``start .. start+N-1`` are used (past
        its end the last row is held; from ``start = 0`` it must cover N steps), or a single
        row, a constant control."""
        if not isinstance(N, (int, np.integer)) or N < 1:
            raise ValueError(f"initial_guess: N must be a positive number of steps, got {N!r}")
        dyn = self.dynamics
        x = self.x0 if x is None else x
        kind = self.config.initial_guess
        if not isinstance(kind, str):  # a path of configurations (PositionGuess)
            return position_guess(self, N, x, start).U.copy()
        if kind == "zeros":
            return np.zeros((N, dyn.nu))
        if kind == "gravity_compensation":
            return np.tile(dyn.gravity_compensation(x), (N, 1))
        if kind == "hold":
            try:
                return np.tile(dyn.hold_torques(x), (N, 1))
            except SimulationError as e:
                raise ConfigError(f"initial_guess: hold torques failed: {e}") from None
        path = self.config.resolve_path(kind)
        U = self._guess_file(path, dyn.nu)
        if U.shape[0] == 1:  # one row: a constant control (e.g. standing torques)
            return np.tile(U[0], (N, 1))
        if start == 0 and U.shape[0] < N:
            raise ConfigError(
                f"initial_guess: {path} has {U.shape[0]} rows; the task needs {N} (one per time "
                f"step) or 1 (a constant control)"
            )
        return U[np.minimum(np.arange(start, start + N), U.shape[0] - 1)].copy()

    def _guess_file(self, path: Path, nu: int) -> np.ndarray:
        """U: [rows, nu] read from the initial_guess file ``path`` (checked: size, shape,
        finite values)."""
        if not path.exists():
            raise ConfigError(
                f"initial_guess: expected zeros, gravity_compensation, hold or a file; "
                f"no such file {path}"
            )

        # rows: at most the whole trajectory (a file may hold more: a generous floor)
        rh = self.config.receding_horizon
        rows = rh.resolves * rh.shift_steps + rh.window_steps if rh else self.config.steps
        cap = inputs.table_cap(rows + 1, nu)
        if path.suffix == ".npz":
            inputs.check_npz(path, "initial_guess:", cap)
        else:
            inputs.check_file(path, "initial_guess:", cap)
        try:
            if path.suffix == ".npz":
                with np.load(path, allow_pickle=False) as d:
                    U = np.asarray(d["U"], float)
            else:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # an empty file is reported below
                    U = np.loadtxt(path, delimiter=",", ndmin=2)
        except Exception as e:  # noqa: BLE001 - its message may quote the file: not shown
            raise ConfigError(
                f"initial_guess: could not read {path}: {_unquoted(e, path.suffix == '.npz')}"
            ) from None
        if U.size == 0:
            raise ConfigError(f"initial_guess: {path} is empty")
        if U.ndim != 2 or U.shape[1] != nu:
            raise ConfigError(f"initial_guess: {path} must hold U with {nu} columns")
        if not np.all(np.isfinite(U)):
            raise ConfigError(f"initial_guess: {path} holds NaN or infinite values")
        return U

    def problem(self, x0: np.ndarray | None = None, t0: float = 0.0) -> Problem:
        """The optimal control problem from x0: [nx] (default: the task's initial state; a
        given x0 is checked and its quaternions normalized, ``checked_state``)."""
        return Problem(
            self.dynamics, self.cost, self.x0 if x0 is None else self.checked_state(x0), t0
        )

    def checked_state(self, x0) -> np.ndarray:
        """A user's initial state x0: [nx] checked (shape, finite) with its quaternions
        normalized like the task file's. ValueError otherwise."""
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (self.dynamics.nx,):
            raise ValueError(f"x0 must have shape [{self.dynamics.nx}] (nx), got {x0.shape}")
        check_finite("x0", x0)  # names the entry, as ilqr.solve does
        return self.dynamics.layout.normalize(x0, "x0")


def _unquoted(e: Exception, npz: bool) -> str:
    """What went wrong reading a guess file, without the file's content (numpy's messages
    quote the text it could not read): where it happened, if the message says."""

    if npz:
        return "not a NumPy .npz file holding an array U (docs/task-format.md)"
    where = re.search(r"at row (\d+), column (\d+)", str(e))
    if where:
        return (
            f"row {int(where[1]) + 1}, column {where[2]}: not a number (expected numbers "
            "separated by commas, one row per time step; docs/task-format.md)"
        )
    if isinstance(e, ValueError):
        return "not a table of comma-separated numbers (docs/task-format.md)"
    return type(e).__name__


def _coordinates(layout) -> tuple:
    """What a state and an input vector mean: each named block's coordinates, and the
    actuators in input order."""
    blocks = tuple(sorted((name, b.coords) for name, b in layout.primitives.items()))
    return blocks, tuple(layout.actuators)
