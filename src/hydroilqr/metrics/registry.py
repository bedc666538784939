"""The metric registry: every metric by name, with what it computes, plots and adds to a
sweep. The families (``common``, ``cartpole``, ``objects``, ``kinova``, ``cheetah``, ``terms``)
register themselves when ``hydroilqr.metrics`` is imported."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from hydroilqr.problem.errors import ConfigError


@dataclass(frozen=True)
class Report:
    """A table of a metric's numbers on the results page, one row per task that computes it:
    ``columns`` are (header, fn(metrics) -> cell text); ``figures`` are plot files of the
    metric linked from each row (written beside the page)."""

    title: str
    intro: str
    columns: tuple[tuple[str, Callable], ...]
    figures: tuple[str, ...] = ()


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
    headline: the keys that say in a few numbers whether a solve did its job (the results
        page's headline column): (label, key, format, scale) each; headline_more: fn(metrics)
        -> more such strings, for keys that vary by task (a term's name).
    moves_object: the task moves an object to rest (the results page plays it back).
    sweep_panels: (key, axis label) panels of sweep.png above the final cost.
    sweep_plot: fn(path, points_dir, task_config, param_keys, rows) -> bool, writing
        ``sweep_plot_file`` from the stored sweep points (False: nothing to draw).
    report: a table of its own on the results page (``Report``).
    """

    name: str
    compute: Callable
    plot: Callable | None = None
    files: tuple[str, ...] | Callable = ()
    sweep_columns: tuple[str, ...] = ()
    sweep_extra_columns: tuple[str, ...] = ()
    sweep_arrays: Callable | None = None
    validate: Callable | None = None
    headline: tuple[tuple[str, str, str, float], ...] = ()
    headline_more: Callable | None = None
    moves_object: bool = False
    sweep_panels: tuple[tuple[str, str], ...] = ()
    sweep_plot: Callable | None = None
    sweep_plot_file: str = ""
    report: Report | None = None

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


def _number(m: dict, key: str, fmt: str, scale: float) -> str | None:
    v = m.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    return format(v * scale if scale != 1.0 else v, fmt)


def headline(names, m: dict) -> str:
    """The headline numbers of metrics ``names`` found in the metrics dict ``m``, short; each
    once where two metrics share a key (``kinova`` extends ``object``)."""
    parts: list[str] = []
    for name in names:
        entry = get(name)
        found = [
            f"{label} {s}"
            for label, key, fmt, scale in entry.headline
            if (s := _number(m, key, fmt, scale)) is not None
        ]
        more = entry.headline_more(m) if entry.headline_more is not None else []
        parts += [p for p in found + more if p not in parts]
    return ", ".join(parts)


def moves_object(names) -> bool:
    """Some metric of ``names`` is of an object moved to rest."""
    return any(get(n).moves_object for n in names)


def sweep_panels(names) -> list[tuple[str, str]]:
    """The (key, axis label) panels metrics ``names`` add to sweep.png, each once."""
    out: list[tuple[str, str]] = []
    for n in names:
        out += [p for p in get(n).sweep_panels if p not in out]
    return out


def sweep_plots(names) -> list[tuple[str, Callable]]:
    """(file name, plot function) of the sweep plots of metrics ``names``."""
    return [(get(n).sweep_plot_file, get(n).sweep_plot) for n in names if get(n).sweep_plot]


def reports() -> list[tuple[str, Report]]:
    """(metric name, report) of every registered metric that has one."""
    return [(name, m.report) for name, m in METRICS.items() if m.report is not None]
