"""Task metrics, by name (``metrics: [default, cartpole_wall]`` in a task file): the one registry.

Every metric is a ``Metric``: a compute function (task, solution) -> dict of JSON-able values
(merged into summary.json ``metrics``), optionally a plot (task, solution, out) with the file
names it writes, the sweep table columns it adds, arrays a sweep point stores, and a
``validate(task)`` hook that checks its ``metric_params`` before any solve (ConfigError).

The families register themselves when this package is imported: ``common`` (default,
contacts), ``cartpole`` (cartpole_wall), ``objects`` (object), ``kinova`` (kinova, an alias of
object plus the arm's name for the contact-polygon count), ``cheetah``, ``terms`` (terms: the
task-space cost terms' final errors), ``flight`` (flight: a legged robot's flight phases and
its base's travel). Contact metrics query
the geometry of every stored state (touching pairs and their contact polygons,
``Dynamics.contact_query``; signed distances): no contact solve, the states themselves; the
contact timeline and the cheetah's foot loads also use the contact solve of each step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from hydroilqr.problem.config import ConfigError


@dataclass(frozen=True)
class Metric:
    """A registered metric.

    compute: fn(task, sol) -> dict, merged into summary.json ``metrics``.
    plot: fn(task, sol, out) writing ``files`` into the run directory ``out`` (or None).
    files: the plot's file names, or fn(metric_params) -> names where they depend on the
        task's parameters (e.g. named after a body).
    sweep_columns: columns a sweep table always shows (after final_cost) for tasks with this
        metric; sweep_extra_columns: shown after the solve's own columns where points have them.
    sweep_arrays: fn(task, X) -> {name: array} stored with each sweep point's trajectory.
    validate: fn(task) raising ConfigError (one line) on bad ``metric_params``; runs before
        any solve.
    """

    name: str
    compute: Callable
    plot: Callable | None = None
    files: tuple[str, ...] | Callable = ()
    sweep_columns: tuple[str, ...] = ()
    sweep_extra_columns: tuple[str, ...] = ()
    sweep_arrays: Callable | None = None
    validate: Callable | None = None

    def file_names(self, params: dict | None = None) -> tuple[str, ...]:
        if callable(self.files):
            return tuple(self.files(dict(params or {})))
        return tuple(self.files)


METRICS: dict[str, Metric] = {}


def register(m: Metric) -> Metric:
    METRICS[m.name] = m
    return m


def metric(name: str, **fields):
    """Decorator: registers fn(task, sol) -> dict as metric ``name`` (``fields``: the other
    ``Metric`` fields, e.g. plot=, files=, validate=)."""

    def deco(fn):
        register(Metric(name, compute=fn, **fields))
        return fn

    return deco


def get(name: str) -> Metric:
    if name not in METRICS:
        raise ConfigError(f"metrics: unknown metric {name!r} (known: {', '.join(METRICS)})")
    return METRICS[name]


def validate(task) -> None:
    """Checks the task's metric names and every selected metric's ``metric_params`` (ConfigError
    with one line); builds the task's plant where a check needs it. No solve."""
    for name in task.config.metrics:
        m = get(name)
        if m.validate is not None:
            m.validate(task)
    common.validate_camera(task)


def compute(task, sol) -> dict:
    out: dict = {}
    for name in task.config.metrics:
        out.update(get(name).compute(task, sol))
    return out


def plot(task, sol, out) -> None:
    """Writes the plots of the task's metrics into ``out`` (each plot function once)."""
    done = set()
    for name in task.config.metrics:
        m = get(name)
        if m.plot is not None and m.plot not in done:
            done.add(m.plot)
            m.plot(task, sol, out)


def plot_files(names=None, params: dict | None = None) -> set[str]:
    """File names the plots of metrics ``names`` write (default every registered metric; plots
    named after ``metric_params`` only where ``params`` is given)."""
    names = list(METRICS) if names is None else names
    files: set[str] = set()
    for name in names:
        m = METRICS.get(name)
        if m is None or (callable(m.files) and params is None):
            continue
        files.update(m.file_names(params))
    return files


def sweep_columns(names) -> tuple[list[str], list[str]]:
    """(columns always shown, columns shown where points have them) of metrics ``names``."""
    lead: list[str] = []
    extra: list[str] = []
    for name in names:
        m = get(name)
        lead += [c for c in m.sweep_columns if c not in lead]
        extra += [c for c in m.sweep_extra_columns if c not in extra]
    return lead, extra


def sweep_arrays(task, X) -> dict:
    """Arrays the task's metrics store with a sweep point's trajectory X: [T, nx]."""
    out: dict = {}
    for name in task.config.metrics:
        m = get(name)
        if m.sweep_arrays is not None:
            out.update(m.sweep_arrays(task, X))
    return out


def _fixed(x) -> str:
    """An element of an array on the terminal: a float fixed-point to 4 decimals (no -0.0000),
    a nested list in brackets, anything else as str."""
    if isinstance(x, (list, tuple)):
        return "[" + ", ".join(_fixed(e) for e in x) + "]"
    if isinstance(x, float):
        text = f"{x:.4f}"
        return text[1:] if text.startswith("-") and float(text) == 0.0 else text
    return str(x)


def terminal_value(v) -> str:
    """A metric on the terminal (JSON keeps full precision): a float to 4 significant digits,
    an array or list of numbers fixed-point, ``[0.7990, -0.0005, 0.0958]``."""
    if hasattr(v, "tolist") and not isinstance(v, float):  # numpy arrays and scalars
        v = v.tolist()
    if isinstance(v, (list, tuple)):
        return _fixed(v)
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def summary_lines(m: dict) -> list[str]:
    """Console lines for a metrics dict: its scalars and arrays, then the final error per Qf
    block."""
    fmt = terminal_value
    shown = {k: v for k, v in m.items() if not isinstance(v, (dict, list))}
    lines = ["metrics: " + ", ".join(f"{k}={fmt(v)}" for k, v in shown.items())]
    ratio = command_limit_ratio(m) if m.get("commands_beyond_limits") else None
    if ratio is not None:
        lines.append(
            f"note: {m['commands_beyond_limits']} planned commands exceed their actuator's "
            f"effort limit (up to {ratio[0]:.3g} times the limit, {ratio[1]}); the plant "
            "applies the limit there, so "
            "the trajectory is what the clipped command gives (the cost prices the command)"
        )
    if m.get("final_error"):
        lines.append(
            "final error |x_N - x_nom| per Qf block: "
            + ", ".join(f"{k}={fmt(v)}" for k, v in m["final_error"].items())
        )
    return lines


# The families register their metrics (after the registry above exists).
from hydroilqr.metrics import cartpole, cheetah, common, flight, kinova, objects, terms  # noqa: E402, F401
from hydroilqr.metrics.common import (  # noqa: E402, F401
    beyond_limits,
    command_limit_ratio,
    contact_pairs,
    default_metrics,
    geometry_ids,
    involves,
    max_contact_faces,
    signed_distance,
)
