"""The ``search:`` section: a sampling search over spline knots before iLQR."""

from __future__ import annotations

import math
from dataclasses import dataclass

from hydroilqr.problem.errors import ConfigError

SEARCH_METHODS = ("predictive", "cem", "mppi")  # search.method
SEARCH_SPACES = ("torque", "position")  # search.space
SEARCH_ORDERS = (0, 1, 3)  # search.order: zero-order hold, linear, cubic
SEARCH_SELECTS = ("goal", "cost", "transfer", "robust")  # search.select
MAX_SEARCH_SAMPLES = 100_000  # samples of one search iteration


@dataclass
class SearchConfig:
    """A sampling search over spline knots before iLQR (``hydroilqr search``, and ``solve``
    on a task with a ``search:`` section; ``solver/sampling.py``, ``solver/search.py``)."""

    method: str = "cem"  # predictive | cem (with iCEM's colored noise and elites kept) | mppi
    samples: int = 64  # rollouts per iteration (the current mean among them)
    iterations: int = 20
    knots: int = 8  # spline knots per actuator over the horizon (1 to the task's steps)
    order: int = 1  # spline order: 0 (zero-order hold), 1 (linear), 3 (cubic)
    # torque: knots are the actuators' commands; position: joint position targets on the
    # actuated joints, tracked by the PD+ law of playback (gains kp, kd) with gravity
    # compensation as feed-forward
    space: str = "torque"
    # sampling standard deviation: in torque space a fraction of each actuator's effort limit
    # (1 N·m or N without one); in position space in the joint's units (rad or m)
    noise: float = 0.3
    elites: int = 8  # cem: samples the mean and spread are refit to
    elite_memory: float = 0.3  # cem: fraction of the elites kept into the next iteration
    colored_noise: float = 2.0  # noise exponent β of a 1/f^β spectrum over the knots (0: white)
    smoothing: float = 0.1  # cem: weight of the previous mean and spread in each refit
    temperature: float = 0.1  # mppi: λ as a fraction of the iteration's cost spread
    kp: float = 100.0  # position space: PD+ stiffness (N·m/rad or N/m)
    kd: float = 10.0  # position space: PD+ damping (N·m·s/rad or N·s/m)
    seed: int = 0
    polish: int = 1  # solve: iLQR from the best this-many distinct samples (0: search only)
    # solve: iLQR from the task's own initial guess too, as iLQR alone solves the task (its
    # continuation stages included), the last of the polished candidates: select then never
    # passes over a plan iLQR alone would have found (with polish 0: not run)
    polish_guess: bool = True
    # goal: the first polished plan meeting the goal, else the lowest cost; cost: the lowest
    # cost; transfer: the first whose PD+ playback (half speed, finer simulation) meets it;
    # robust: the one whose perturbed re-solves (robust_runs, robust_noise) meet it most often
    select: str = "goal"
    # solve: while no polished plan meets the task's goal, search again (a seed drawn from
    # seed and the restart's number) and polish that search's best, at most this many times
    restarts: int = 0
    robust_runs: int = 3  # select robust: re-solves per polished candidate that meets the goal
    # select robust: each re-solve's relative perturbation of the candidate's torques (as
    # ``hydroilqr robustness --noise``)
    robust_noise: float = 1e-9
    batches: int = 0  # evaluation batches per iteration (0: one per worker)
    # receding-horizon search (long motions): windows of this many steps (0: the whole
    # horizon at once), each keeping its first shift_steps (0: half the window); knots and
    # iterations are per window
    window_steps: int = 0
    shift_steps: int = 0


def check_searchable(cfg) -> None:
    """``hydroilqr search`` / ``solve`` / ``robustness --search`` of a task (a TaskConfig)
    with a ``search:`` section: ConfigError for a receding-horizon solve (its windows are
    iLQR's; a search's are ``search.window_steps``). ``mpc.planner: sampling`` reads the
    section on any task."""
    if cfg.search is not None and cfg.receding_horizon is not None:
        raise ConfigError(
            "search: a receding-horizon task cannot be searched (one horizon only; set "
            "receding_horizon=null and search.window_steps for a search window by window)"
        )


def validate_search(sc: SearchConfig | None, steps: int, goal: bool = True) -> None:
    """ConfigError naming the first invalid ``search:`` setting (none: nothing to check) of a
    task of ``steps`` time steps (``goal``: whether the task declares one)."""
    if sc is None:
        return
    for key, value, choices in (
        ("method", sc.method, SEARCH_METHODS),
        ("space", sc.space, SEARCH_SPACES),
        ("order", sc.order, SEARCH_ORDERS),
        ("select", sc.select, SEARCH_SELECTS),
    ):
        if value not in choices:
            raise ConfigError(
                f"search.{key}: expected one of {', '.join(map(str, choices))}, got {value!r}"
            )
    for name, ok, rule in (
        ("samples", 2 <= sc.samples <= MAX_SEARCH_SAMPLES, f"from 2 to {MAX_SEARCH_SAMPLES}"),
        ("iterations", 1 <= sc.iterations <= 100_000, "from 1 to 100000"),
        ("knots", 1 <= sc.knots <= steps, f"from 1 to the task's {steps} steps"),
        ("elites", sc.elites >= 1, ">= 1 (at most search.samples are used)"),
        ("seed", sc.seed >= 0, ">= 0"),
        ("polish", 0 <= sc.polish <= 100, "from 0 to 100"),
        ("batches", 0 <= sc.batches <= 10_000, "from 0 (one per worker) to 10000"),
        ("robust_runs", 1 <= sc.robust_runs <= 100, "from 1 to 100"),
        ("restarts", 0 <= sc.restarts <= 100, "from 0 to 100"),
        ("knots", sc.knots <= (sc.window_steps or steps), "at most search.window_steps"),
        ("window_steps", sc.window_steps >= 0, ">= 0 (0: the whole horizon at once)"),
        (
            "shift_steps",
            0 <= sc.shift_steps <= max(sc.window_steps, 0),
            "from 0 (half the window) to search.window_steps",
        ),  # fmt: skip
    ):
        if not ok:
            raise ConfigError(f"search.{name}: must be {rule}, got {getattr(sc, name)!r}")
    for name, ok, rule in (
        ("noise", 0 < sc.noise < math.inf, "a finite number > 0"),
        ("elite_memory", 0 <= sc.elite_memory <= 1, "in [0, 1]"),
        ("colored_noise", 0 <= sc.colored_noise <= 10, "in [0, 10]"),
        ("smoothing", 0 <= sc.smoothing < 1, "in [0, 1)"),
        ("temperature", 0 < sc.temperature < math.inf, "a finite number > 0"),
        ("kp", 0 <= sc.kp < math.inf and (sc.kp > 0 or sc.space != "position"), "finite, > 0"),
        ("kd", 0 <= sc.kd < math.inf, "a finite number >= 0"),
        ("robust_noise", 0 < sc.robust_noise < math.inf, "a finite number > 0"),
    ):
        if not ok:  # (NaN fails every comparison)
            raise ConfigError(f"search.{name}: must be {rule}, got {getattr(sc, name)!r}")
    if sc.restarts and not (goal and sc.polish >= 1):
        raise ConfigError(
            f"search.restarts: {sc.restarts} needs search.polish >= 1 and a goal: section (a "
            "restart searches again when no polished plan meets the goal; set "
            "search.restarts=0 to search once)"
        )
