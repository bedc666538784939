"""The results page: solve built-in tasks and write ``docs/results.md`` + ``docs/results.json``.

Every number the documentation quotes comes from this page, which records the command that
produced it and the environment it ran in (contact-rich solves move with last-bit
floating-point differences, so numbers are comparable only within one environment).

The page is a list of sections. A section is a function ``f(results, context) -> Section |
None`` in ``SECTIONS``; the default one is the table of solves, whose columns are the entries
of ``COLUMNS`` (a header and a function of one ``TaskResult``). Other studies add a section
(e.g. a bench table) with ``SECTIONS.append(fn)`` or a column (e.g. a playback gap) with
``COLUMNS.append(Column(...))`` before calling :func:`generate`.
"""

from __future__ import annotations

import json
import shlex
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from hydroilqr import Task, metrics, solve
from hydroilqr.control.playback import HALF_SPEED, PlaybackSettings, executed_goal, playback
from hydroilqr.io.environment import environment
from hydroilqr.metrics import validate_task
from hydroilqr.metrics.goals import evaluate
from hydroilqr.output.report import json_safe, output_dir
from hydroilqr.output.studies import write_results_page
from hydroilqr.problem.variants import mismatch_overrides
from hydroilqr.studies.robustness import table

DEFAULT_TASKS = (
    "cartpole-wall",
    "kinova-forward",
    "kinova-left",
    "kinova-up",
    "kinova-reach",
    "finger-wheel",
    "finger-spin",
    "hopper-forward",
    "cheetah-trot-1.0",
    "cheetah-trot-0.5",
)


@dataclass
class TaskResult:
    """One solved task: the task, its solution, its metrics and the wall time of ``solve``."""

    name: str
    task: object
    sol: object
    metrics: dict
    solve_seconds: float


@dataclass
class Section:
    """A part of the page: a heading, its Markdown body, and the data it adds to the JSON."""

    key: str
    title: str
    markdown: str
    data: object = None


@dataclass
class Column:
    """A column of the solve table: ``value(result)`` is a short string ('' if none)."""

    header: str
    value: Callable[[TaskResult], str]


@dataclass
class Context:
    command: str
    smoke: bool
    overrides: list[str] = field(default_factory=list)
    out: str = "docs"


# ------------------------------------------------------------------------------ the columns


COLUMNS: list[Column] = [
    Column("task", lambda r: f"`{r.name}`"),
    Column("iterations", lambda r: str(r.sol.iterations)),
    Column("final cost", lambda r: f"{r.sol.final_cost:.4g}"),
    Column(
        "status",
        lambda r: r.sol.status + ("" if r.sol.reason == r.sol.status else f" ({r.sol.reason})"),
    ),
    Column("goal", lambda r: _goal_cell(r.task, r.metrics)),
    Column("solve s", lambda r: f"{r.solve_seconds:.1f}"),
    Column("headline metrics", lambda r: metrics.headline(r.task.config.metrics, r.metrics)),
]


def _goal_cell(task, metrics: dict) -> str:
    """PASS / FAIL with the failed checks ('' for a task without a goal)."""

    g = evaluate(task.config.goal, metrics)
    if g["met"] is None:
        return ""
    if g["met"]:
        return "PASS"
    return "FAIL: " + "; ".join(
        f"{c['metric']} {c.get('why', '')}" for c in g["checks"] if not c["passed"]
    )


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def solve_table(results: Sequence[TaskResult], context: Context) -> Section:
    """The default section: one row per task."""
    head = "| " + " | ".join(c.header for c in COLUMNS) + " |"
    rule = "|" + "---|" * len(COLUMNS)
    rows = ["| " + " | ".join(_cell(c.value(r)) for c in COLUMNS) + " |" for r in results]
    note = (
        "`final cost` is the last window's for receding-horizon tasks; `solve s` is the wall "
        "time of `solve()`. Every metric is in `results.json`."
    )
    data = [
        {
            "task": r.name,
            "converged": bool(r.sol.converged),
            "status": r.sol.status,
            "reason": r.sol.reason,
            "goal": _goal_json(r.task, r.metrics),
            "iterations": int(r.sol.iterations),
            "final_cost": float(r.sol.final_cost),
            "solve_seconds": float(r.solve_seconds),
            "metrics": json_safe(r.metrics),
        }
        for r in results
    ]
    return Section("solves", "Solves", "\n".join([head, rule, *rows, "", note]), data)


def _goal_json(task, metrics: dict) -> dict:
    return evaluate(task.config.goal, metrics)


def _moves_an_object(task) -> bool:
    return metrics.moves_object(task.config.metrics)


def transfer_table(results: Sequence[TaskResult], context: Context) -> Section | None:
    """Open-loop playback (``hydroilqr playback RUN --speed 0.5``) of every task that moves an
    object: where the object comes to rest against where the plan puts it to rest, the gap at
    the plan's end, and the task's goal judged on the executed motion."""

    rows, data = [], []
    for r in results:
        if not _moves_an_object(r.task):
            continue
        m, g, verdict = _play(r, PlaybackSettings(**HALF_SPEED))
        ob = m["object"]
        rest = ob.get("resting_gap")
        rows.append(
            f"| `{r.name}` | {'' if rest is None else f'{100 * rest:.1f}'} | "
            f"{100 * ob['final_gap']:.1f} | {100 * m['saturated_fraction']:.1f} | "
            f"{len(m.get('warnings', []))} | {verdict} |"
        )
        data.append(
            {
                "task": r.name,
                "resting_gap_m": rest,
                "final_gap_m": ob["final_gap"],
                "saturated_fraction": m["saturated_fraction"],
                "warnings": m.get("warnings", []),
                "goal_on_executed_motion": g,
            }
        )
    if not rows:
        return None
    head = (
        "| task | resting gap cm | gap at plan end cm | saturated % | warnings | goal |\n"
        "|---|---|---|---|---|---|"
    )
    note = (
        "PD+ (eq. 11) at the paper's gains, plan played at half speed with the feed-forward "
        "scaled to that speed (the default `--feedforward scaled`) on the finer simulation with "
        "the other contact approximation (`hydroilqr playback RUN --speed 0.5`); after the plan "
        "the robot holds its last reference until the object rests (or 3 s). `goal`: the task's "
        "goal judged on the executed motion, at rest (for kinova-up: the lift). kinova-up's "
        "resting gap compares where the planning model's extension drops the lifted ball with "
        "where the real system holds it."
    )
    return Section(
        "transfer", "Transfer (open-loop playback)", "\n".join([head, *rows, "", note]), data
    )


def mismatch_table(results: Sequence[TaskResult], context: Context) -> Section | None:
    """Playback of every task that names model errors (its ``mismatch:`` cases) with the plan's
    own feedback at full speed (``hydroilqr playback RUN --policy ilqr --mismatch NAME``):
    the resting gap on each mismatched "real" system and the goal judged there."""

    rows, data = [], []
    for r in results:
        for name in r.task.config.mismatch:
            truth = mismatch_overrides(r.task.config, name)
            m, g, verdict = _play(
                r, PlaybackSettings(policy="ilqr", speed=1.0, truth_overrides=truth)
            )
            ob = m["object"]
            rest = ob.get("resting_gap")
            rows.append(f"| `{r.name}` | `{name}` | {_gap(rest, ob['unit'])} | {verdict} |")
            data.append(
                {
                    "task": r.name,
                    "case": name,
                    "truth_overrides": truth,
                    "object": ob["name"],
                    "unit": ob["unit"],
                    "resting_gap": rest,
                    "goal_on_executed_motion": g,
                }
            )
    if not rows:
        return None
    head = "| task | mismatch | resting gap | goal |\n|---|---|---|---|"
    note = (
        "The plan's own feedback (`--policy ilqr`, eq. 8) at speed 1 on the finer simulation "
        "with the other contact approximation, whose model differs from the planned one as the "
        "task's `mismatch:` case says (`hydroilqr playback RUN --policy ilqr --mismatch NAME`). "
        "Resting gap: where the compared object (`results.json`: `object`) comes to rest "
        "against where the plan, extended the same way, puts it to rest; goal: the task's goal "
        "judged on the executed motion, at rest."
    )
    return Section(
        "mismatch", "Transfer under model mismatch", "\n".join([head, *rows, "", note]), data
    )


def _play(r: TaskResult, settings) -> tuple[dict, dict, str]:
    """Plays ``r``'s plan back: the playback metrics, the task's goal judged on the executed
    motion, and its verdict (PASS, FAIL, or '' when not judged)."""

    pb = playback(r.task, r.sol, settings)
    g = executed_goal(r.task, r.sol, pb)["goal"]
    return pb.metrics, g, "" if g["met"] is None else ("PASS" if g["met"] else "FAIL")


def _gap(value, unit: str) -> str:
    """A resting gap cell: centimetres for a position, else in the object's own unit."""
    if value is None:
        return ""
    return f"{100 * value:.1f} cm" if unit == "m" else f"{value:.3g} {unit}"


def bench_table(results: Sequence[TaskResult], context: Context) -> Section | None:
    """The latest ``hydroilqr bench ... --out OUT/bench`` (its own command and load), if one
    was run into the results directory: per-iteration time of (a) the paper's method, (a')
    the paper's method on the fast path's contact solver and (b) the fast path, the ratios,
    final costs, and the limit analysis."""
    path = Path(context.out) / "bench" / "bench.json"
    if not path.is_file():
        return None
    doc = json.loads(path.read_text())
    rows = []
    tasks = doc.get("tasks") or {}
    for r in tasks.values() if isinstance(tasks, dict) else tasks:
        a, b, a2 = r.get("paper", {}), r.get("fast", {}), r.get("paper_same_solver", {})
        if not all("median_s" in x for x in (a, b, a2)):
            continue
        lim = r.get("limits", {})
        rows.append(
            f"| `{r['task']}` | {a['median_s']:.3f} | {a2['median_s']:.3f} | {b['median_s']:.3f} "
            f"| {r['speedup_median']:.1f}x | {r['speedup_same_solver_median']:.1f}x | "
            f"{_ratio(r.get('speedup_same_solver_total'))} | "
            f"{a2['final_cost']:.4g} / {b['final_cost']:.4g} "
            f"({r['cost_rel_diff_same_solver']:+.1%}) | "
            + (
                f"{lim['limit_s']:.3f} ({lim['fast_share_of_limit']:.0%}) |"
                if "fast_share_of_limit" in lim
                else " |"
            )
        )
    env = doc.get("environment", {})
    load = env.get("load_average") or env.get("load")
    head = (
        "| task | (a) s/it | (a') s/it | (b) s/it | a/b | a'/b | a'/b mean | cost a' / b | "
        "fastest possible s/it (b reaches) |\n|---|---|---|---|---|---|---|---|---|"
    )
    note = (
        f"From `{env.get('command', 'hydroilqr bench')}` (load {load or 'not recorded'}), "
        "median seconds per iteration measured side by side in one process; a'/b mean: the "
        "ratio of the whole runs' times (the same number of iterations each), which counts "
        "iterations with exact and with secant partials alike. (a): TAMSI, "
        "AutoDiff at every step, serial (the paper's method); (a'): the same on (b)'s contact "
        "solver; (b): the fast path. The fastest possible iteration: one rollout, exact "
        "partials of the needed keypoints on the cheapest path on this machine's cores, "
        "backward pass and line search."
    )
    return Section("bench", "Speed per iteration", "\n".join([head, *rows, "", note]), doc)


def robustness_table(results: Sequence[TaskResult], context: Context) -> Section | None:
    """The latest ``hydroilqr robustness ... --out OUT/robustness[/PART...]`` runs (each with
    its own command and environment), if any were run into the results directory: first the
    goal's pass rate per task, kind of run (solve or closed loop) and seed, a column per BLAS
    kernel set the records were measured on (``environment.blas_core``); then each record's
    table: how many of its perturbed runs met the goal and each of its checks."""

    root = Path(context.out) / "robustness"
    paths = sorted(root.glob("**/robustness.json"), key=lambda p: (len(p.parts), str(p)))
    if not paths:
        return None
    docs = [json.loads(path.read_text()) for path in paths]
    parts = [kernel_table(docs), ""]
    for doc in docs:
        parts += [table(doc), "", _robustness_source(doc), ""]
    note = (
        "Each run is judged by the task's goal (a closed loop by its `mpc.goal`). The "
        "perturbation stands in for last-bit differences between machines: other BLAS kernel "
        "sets and CPUs land in other, equally valid local minima, so these pass rates, not the "
        "single solves above, are the numbers to expect on another machine. Solve times here "
        "are of one Dask worker process each, two at once."
    )
    return Section(
        "robustness",
        "Robustness to last-bit differences",
        "\n".join([*parts, note]),
        docs,
    )


def _column(env: dict) -> str:
    """A record's column of ``kernel_table``: its BLAS kernel set, and its Python and Drake
    where the record names them (the stacks' pass rates side by side)."""
    col = f"{env.get('blas_core') or 'unknown'} kernels"
    python, drake = env.get("python"), env.get("drake")
    if python:
        col += f", Python {'.'.join(str(python).split('.')[:2])}"
        col += f" + Drake {drake}" if drake else ""
    return col


def kernel_table(docs: Sequence[dict]) -> str:
    """Goal pass rates by task, kind of run and seed (rows) and by BLAS kernel set and stack
    (columns: ``environment.blas_core`` of each record, with its Python X.Y and Drake where
    recorded; '-' where a row was not measured there)."""
    kernels: list[str] = []
    rows: dict[tuple, dict[str, list[str]]] = {}
    for doc in docs:
        blas = _column(doc.get("environment") or {})
        kernels += [blas] if blas not in kernels else []
        kind = (
            "closed loop" if doc.get("mpc") else "search + polish" if doc.get("search") else "solve"
        )
        for t in doc["tasks"]:
            cell = f"{t['goal_met']} of {t['runs']}" if t["goal_declared"] else "no goal"
            cells = rows.setdefault((t["task"], kind, doc.get("seed", 0)), {})
            cells.setdefault(blas, [])
            cells[blas] += [cell] if cell not in cells[blas] else []
    head = ["task", "run", "seed", *(f"goal met, {k}" for k in kernels)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    first = {}  # (a task's rows together, where it first appears; then by kind and seed)
    for task, _, _ in rows:
        first.setdefault(task, len(first))
    for (task, kind, seed), cells in sorted(rows.items(), key=lambda r: (first[r[0][0]], r[0])):
        row = [f"`{task}`", kind, str(seed), *(", ".join(cells.get(k, ["-"])) for k in kernels)]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def _robustness_source(doc: dict) -> str:
    """Where a robustness record came from: its command, code, kernels, load and runs, and
    what was removed from it since."""
    env = doc.get("environment", {})
    runs = (
        f"{doc['runs']} closed loops per task (lock-step), each first plan's initial guess "
        if doc.get("mpc")
        else f"{doc['runs']} solves per task, each from the initial guess "
    )
    return (
        f"From `{doc.get('command') or 'hydroilqr robustness'}` at code "
        f"{env.get('code') or 'unknown'} (Python {env.get('python') or 'unknown'}, Drake "
        f"{env.get('drake') or 'unknown'}, BLAS kernels {env.get('blas_core') or 'unknown'}, "
        f"load {env.get('load_average', 'not recorded')}): {runs}perturbed by a relative "
        f"{doc['noise']:g}"
        + (
            "; each plan also played back as in the transfer section (the goal judged on "
            "the executed motion; the object's resting gap)."
            if doc.get("transfer")
            else "."
        )
        + _removed(doc)
    )


def _removed(doc: dict) -> str:
    """What was taken out of a record after its run (its ``removed``: task -> why), so that its
    command, which still names those tasks, is not read as the whole record."""
    gone = doc.get("removed") or {}
    return "".join(f" Since removed: `{task}` ({why})." for task, why in gone.items())


def search_table(results: Sequence[TaskResult], context: Context) -> Section | None:
    """Per task with a ``hydroilqr robustness --search`` record under OUT/robustness: the goal's
    pass rate of iLQR alone (its records without --search) beside that of search + polish,
    per BLAS kernel set, and the median wall time of one search + polish run; then the
    search's samples per second with each number of workers (``hydroilqr search TASK
    --throughput 1,2 --out OUT/search/TASK``: OUT/search/**/throughput.json)."""
    root = Path(context.out)
    docs = [json.loads(p.read_text()) for p in sorted(root.glob("robustness/**/robustness.json"))]
    docs = [d for d in docs if not d.get("smoke") and not d.get("mpc")]
    rates: dict[tuple, dict] = {}
    for doc in docs:
        blas = (doc.get("environment") or {}).get("blas_core") or "unknown"
        for t in doc["tasks"]:
            cell = rates.setdefault((t["task"], blas), {})
            key = "search" if doc.get("search") else "alone"
            cell.setdefault(key, []).append(f"{t['goal_met']} of {t['runs']}")
            if doc.get("search"):
                secs = sorted(r.get("seconds", 0.0) for r in t.get("results", []))
                cell.setdefault("seconds", []).append(secs[len(secs) // 2] if secs else None)
    rows = [
        f"| `{task}` | {blas} | {', '.join(c.get('alone', ['-']))} | {', '.join(c['search'])} | "
        + ", ".join("-" if v is None else f"{v:.0f}" for v in c["seconds"])
        + " |"
        for (task, blas), c in sorted(rates.items())
        if "search" in c
    ]
    if not rows:
        return None
    head = (
        "| task | kernels | goal met, iLQR alone | goal met, search + polish | "
        "s per search + polish run (median) |\n|---|---|---|---|---|"
    )
    parts = [head, *rows, "", *_throughput_rows(root)]
    note = (
        "iLQR alone: `hydroilqr robustness TASK` (with the task's approach stage, from its "
        "guess perturbed by a hair); search + polish: `hydroilqr robustness TASK --search` "
        "(the task's search with seed k - 1 in run k, then iLQR from its best samples, as "
        "`hydroilqr solve` runs it). Run times are of one Dask worker each, several at once, on "
        "a machine that may be shared with other work (each record's load is below)."
    )
    return Section("search", "Search across basins", "\n".join([*parts, note]), rates_json(rates))


def rates_json(rates: dict) -> list[dict]:
    return [{"task": t, "blas_core": b, **c} for (t, b), c in sorted(rates.items())]


def _throughput_rows(root: Path) -> list[str]:
    """The samples-per-second table of every throughput.json under OUT/search ([] if none)."""
    lines = []
    for path in sorted(root.glob("search/**/throughput.json")):
        doc = json.loads(path.read_text())
        env = doc.get("environment") or {}
        rows = doc.get("rows") or []
        base = rows[0]["samples_per_second"] if rows else None
        for r in rows:
            lines.append(
                f"| `{doc.get('task')}` | {r['workers']} | {r['samples_per_second']:.1f} | "
                f"{r['samples_per_second'] / base:.2f}x | "
                f"{1e3 * r['batch_overhead_seconds']:.0f} | {100 * r['cpu_share']:.0f}% | "
                f"{env.get('blas_core') or 'unknown'}, load {env.get('load_average', '?')} |"
            )
    if not lines:
        return []
    head = (
        "| task | workers | samples/s | vs 1 worker | batch overhead ms | "
        "share of a core per worker | kernels, load |\n|---|---|---|---|---|---|---|"
    )
    note = (
        "Samples per second of the search's rollouts with 1 and 2 local workers, measured "
        "side by side in one run (`hydroilqr search TASK --throughput 1,2`); the batch "
        "overhead is an empty batch's round trip. A share of a core below 100% means the "
        "machine was busy with other work: the ratio then says more about that than about "
        "the workers."
    )
    return [head, *lines, "", note, ""]


def _ratio(v) -> str:
    """A speed-up cell: '1.5x', or '-' where the bench file has none (an older bench.json)."""
    return "-" if v is None else f"{v:.1f}x"


def metric_reports(results: Sequence[TaskResult], context: Context) -> list[Section]:
    """A table per metric that declares a report (``Metric.report``), rows per task that
    computes it: its plan, the plan's PD+ playback at full speed on the finer simulation
    (``hydroilqr playback RUN --speed 1``) and, where one was run into the results directory
    (``hydroilqr mpc TASK --out OUT/mpc/TASK``), its latest closed loop (``loop_reports``);
    the report's figures are written beside the page (``OUT/results/TASK/``) and linked from
    the plan's row."""
    sections = []
    for name, rep in metrics.reports():
        rows, data = [], []
        for r in results:
            if name not in r.task.config.metrics:
                continue
            links = _report_figures(r, rep.figures, context)
            for kind, m in _report_motions(r, context):
                cells = [f"`{r.name}`", kind, *(fn(m) for _, fn in rep.columns)]
                fig = links if kind == "plan" else ""
                rows.append("| " + " | ".join(_cell(c) for c in [*cells, fig]) + " |")
                data.append(
                    {"task": r.name, "motion": kind,
                     **{h: c for (h, _), c in zip(rep.columns, cells[2:])}}
                )  # fmt: skip
        if not rows:
            continue
        headers = ["task", "motion", *(h for h, _ in rep.columns), "figures"]
        md = "\n".join(
            [rep.intro + REPORT_MOTIONS, "", "| " + " | ".join(headers) + " |",
             "|" + "---|" * len(headers), *rows]
        )  # fmt: skip
        sections.append(Section(f"report_{name}", rep.title, md, data))
    return sections


REPORT_MOTIONS = (
    " Rows: `plan` the solved plan; `playback` the plan executed by PD+ at full speed on the "
    "finer simulation (`hydroilqr playback RUN --speed 1`); `closed loop` the latest "
    "`hydroilqr mpc TASK --out OUT/mpc/TASK` in the results directory, if any (its command "
    "and planner in its mpc.json)."
)


def _report_motions(r: TaskResult, context: Context) -> list[tuple[str, dict]]:
    """(motion, metrics) of a task's report rows: the plan, its playback, a closed loop."""
    out = [("plan", r.metrics)]
    try:
        pb = playback(r.task, r.sol, PlaybackSettings(speed=1.0))
        out.append(("playback", executed_goal(r.task, r.sol, pb)["metrics"]))
    except Exception as e:  # noqa: BLE001 - a failed playback is a row saying so
        out.append(("playback", {"error": f"{type(e).__name__}: {e}"[:200]}))
    path = Path(context.out) / "mpc" / r.name / "mpc.json"
    if path.is_file():
        doc = json.loads(path.read_text())
        out.append((f"closed loop ({doc.get('planner', 'ilqr')})", doc.get("metrics") or {}))
    return out


def _report_figures(r: TaskResult, figures: Sequence[str], context: Context) -> str:
    """Writes the task's metric plots into OUT/results/TASK/ and links those named."""
    if not figures:
        return ""
    where = Path(context.out) / "results" / r.name
    where.mkdir(parents=True, exist_ok=True)
    metrics.plot(r.task, r.sol, where)
    return ", ".join(f"[{f}](results/{r.name}/{f})" for f in figures if (where / f).exists())


SECTIONS: list[Callable[[Sequence[TaskResult], Context], Section | list[Section] | None]] = [
    solve_table,
    metric_reports,
    transfer_table,
    mismatch_table,
    robustness_table,
    search_table,
    bench_table,
]


# ------------------------------------------------------------------------------ the page


def command_line(
    tasks: Sequence[str], out: str | Path, smoke: bool, overrides: Sequence[str]
) -> str:
    """The ``hydroilqr results ...`` command that regenerates a page with these arguments."""
    argv = ["hydroilqr", "results", *tasks]
    if smoke:
        argv.append("--smoke")
    for o in overrides:
        argv += ["--set", o]
    argv += ["--out", str(out)]
    return shlex.join(argv)


def solve_tasks(
    tasks: Sequence[str],
    overrides: Sequence[str] = (),
    smoke: bool = False,
    progress: Callable[[str], None] | None = None,
) -> list[TaskResult]:
    """Loads, solves and measures each task through the public API."""

    results = []
    for name in tasks:
        task = Task.load(name, list(overrides), smoke=smoke)
        validate_task(task)
        if progress:
            progress(f"solving {name}{' (smoke)' if smoke else ''}")
        t0 = time.perf_counter()
        sol = solve(task)
        seconds = time.perf_counter() - t0
        results.append(TaskResult(name, task, sol, metrics.compute(task, sol), seconds))
        if progress:
            progress(
                f"{name}: {sol.iterations} iterations, cost {sol.final_cost:.4g}, {seconds:.1f} s"
            )
    return results


def render(
    results: Sequence[TaskResult],
    context: Context,
    env: dict,
    sections: Sequence[Callable] | None = None,
) -> tuple[str, dict]:
    """The page as Markdown and as a JSON-able dict."""
    made: list[Section] = []
    for f in sections or SECTIONS:
        s = f(results, context)
        made += s if isinstance(s, list) else [s] if s is not None else []
    env_line = ", ".join(
        f"{k} {v}"
        for k, v in env.items()
        if k != "command" and v not in (None, "", []) and not isinstance(v, (list, dict))
    )
    feats = env.get("cpu_features") or []
    lines = [
        "# Results",
        "",
        "Generated; do not edit. Regenerate with:",
        "",
        "```bash",
        context.command,
        "```",
        "",
        f"Environment: {env_line}" + (f", cpu_features {' '.join(feats)}" if feats else "") + ".",
        "Numbers of contact-rich solves are comparable only within one environment "
        "(code, package versions, BLAS kernels): other kernel sets land in other, equally "
        "valid local minima, and the pass rates under last-bit perturbations (section "
        '"Robustness to last-bit differences") are the numbers to expect there.',
    ]
    if context.smoke:
        lines += ["", "**Smoke-sized tasks** (`--smoke`): not the real problems."]
    for s in made:
        lines += ["", f"## {s.title}", "", s.markdown]
    page = {
        "command": context.command,
        "smoke": context.smoke,
        "overrides": list(context.overrides),
        "environment": json_safe(env),
        "sections": {s.key: json_safe(s.data) for s in made},
    }
    return "\n".join(lines) + "\n", page


#: The page this repository ships (its numbers estimate how long a run takes).
SHIPPED_PAGE = Path(__file__).resolve().parents[3] / "docs" / "results.json"


def estimate(tasks: Sequence[str], smoke: bool, page: Path = SHIPPED_PAGE) -> str:
    """How long ``tasks`` took on the machine that wrote ``page`` (the shipped results
    page): its whole run if it recorded one and ran the same tasks, else its solves of
    these tasks alone; '' when there is no such page or it has none of them."""
    try:
        doc = json.loads(page.read_text())
    except (OSError, ValueError):
        return ""
    solves = {
        s.get("task"): s.get("solve_seconds") for s in doc.get("sections", {}).get("solves", [])
    }
    known = [solves[t] for t in tasks if isinstance(solves.get(t), (int, float))]
    if not known or smoke:
        return ""
    env = doc.get("environment") or {}
    where = f"{env.get('cpu', 'its CPU')}, {env.get('cores', '?')} cores"
    same = sorted(tasks) == sorted(solves) and doc.get("wall_seconds")
    if same:
        return f"about {_duration(doc['wall_seconds'])} on the machine of docs/results.md ({where})"
    return (
        f"the solves alone took {_duration(sum(known))} on the machine of docs/results.md "
        f"({where}; {len(known)} of the {len(tasks)} tasks), and the playback, mismatch and "
        "bench sections add to that"
    )


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.0f} min"


def generate(
    tasks: Sequence[str] = DEFAULT_TASKS,
    out: str | Path = "docs",
    smoke: bool = False,
    overrides: Sequence[str] = (),
    command: str | None = None,
    sections: Sequence[Callable] | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Path]:
    """Solves ``tasks`` and writes ``OUT/results.md`` and ``OUT/results.json`` (each
    atomically). ``command``: the line recorded at the top (default: the equivalent
    ``hydroilqr results ...`` command). Returns the paths written, by format."""
    tasks = list(tasks)
    out = output_dir(out)  # created, locked and proven writable before any solve
    wall0 = time.perf_counter()
    context = Context(
        command=command or command_line(tasks, out, smoke, overrides),
        smoke=smoke,
        overrides=list(overrides),
        out=str(out),
    )
    results = solve_tasks(tasks, overrides, smoke, progress)
    env = dict(environment())
    env["command"] = context.command
    md, page = render(results, context, env, sections)
    page["wall_seconds"] = round(time.perf_counter() - wall0, 1)  # (the next run's estimate)
    return write_results_page(out, page, md)
