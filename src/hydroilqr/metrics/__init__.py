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

# The families register their metrics in the registry when imported.
from hydroilqr.metrics import cartpole, cheetah, flight, kinova, objects, terms  # noqa: F401
from hydroilqr.metrics.common import (  # noqa: F401
    beyond_limits,
    block_unit,
    command_limit_ratio,
    contact_pairs,
    default_metrics,
    geometry_ids,
    involves,
    max_contact_faces,
    signed_distance,
    validate_camera,
)
from hydroilqr.metrics.goals import check_names
from hydroilqr.metrics.registry import (  # noqa: F401
    METRICS,
    Metric,
    Report,
    compute,
    get,
    headline,
    metric,
    moves_object,
    plot,
    plot_files,
    register,
    reports,
    sweep_arrays,
    sweep_columns,
    sweep_panels,
    sweep_plots,
)
from hydroilqr.metrics.registry import validate as validate_params


def validate(task) -> None:
    """The task's metric names, every selected metric's ``metric_params`` and the replay
    camera (ConfigError with one line); builds the task's plant where a check needs it."""
    validate_params(task)
    validate_camera(task)


def validate_task(task, mismatch: bool = True) -> None:
    """Everything that can fail on bad input before a solve (ConfigError, one line): the task
    builds (``Task.validate``), its metric names and ``metric_params`` hold, the replay camera
    is well formed, and its goal names metrics the task reports."""
    task.validate(mismatch)
    validate(task)
    check_names(task)


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


def final_error_units(task, m: dict) -> dict[str, str]:
    """Block name -> unit (``block_unit``) of each final error in metrics ``m``."""
    return {k: block_unit(task.dynamics, k) for k in m.get("final_error") or {}}


def summary_lines(m: dict, units: dict | None = None) -> list[str]:
    """Console lines for a metrics dict: its scalars and arrays, then the final error per Qf
    block (``units``: block name -> its unit with a leading space, ``block_unit``)."""
    units = units or {}
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
            + ", ".join(f"{k}={fmt(v)}{units.get(k, '')}" for k, v in m["final_error"].items())
        )
    return lines


def report_rows(names, m: dict) -> dict[str, dict[str, str]]:
    """The results-page report rows (e.g. the cheetah's gait table) of a metrics dict, for a
    task whose ``metrics:`` are ``names``: {metric name: {column header: cell}} (written into
    summary.json, mpc.json and playback.json as ``reports``, so a plan, a closed loop and a
    playback are read in one table)."""
    if not isinstance(m, dict) or "error" in m:
        return {}
    return {
        name: {header: fn(m) for header, fn in rep.columns}
        for name, rep in reports()
        if name in names
    }


def report_lines(rows: dict[str, dict[str, str]], what: str) -> list[str]:
    """Console lines of ``report_rows``: one per report, ``what`` naming the motion."""
    return [
        f"{name} ({what}): " + ", ".join(f"{h} {c}" for h, c in cells.items())
        for name, cells in rows.items()
    ]
