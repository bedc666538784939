"""The files of the studies' commands, each call on ``write_set``'s skeleton
(``output/results.py``): written beside the earlier files, then swapped in whole with Ctrl+C
deferred until they are complete. The studies (``studies/``, ``cli/``) compute the data and
draw nothing into their directories themselves: a plot is drawn by a function these writers
call with a path in their stage.

- a sweep: ``write_sweep_spec`` (sweep_spec.json), ``write_sweep_tables`` (sweep.csv,
  sweep.json and computed.log, one set after every finished point), ``write_sweep_plots``
  (sweep.png and the metrics' sweep plots); its points: ``results.write_sweep_point``;
- ``write_robustness`` (robustness.json);
- ``write_bench`` (bench.json and iterations.png);
- ``write_results_page`` (results.json and results.md, ``hydroilqr results``)."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Callable
from pathlib import Path

from hydroilqr.io.files import atomic_write
from hydroilqr.output.report import json_safe
from hydroilqr.output.results import write_set

SWEEP_SPEC = "sweep_spec.json"
SWEEP_TABLES = ("sweep.csv", "sweep.json")
COMPUTED_LOG = "computed.log"
ROBUSTNESS = "robustness.json"
BENCH_FILES = ("bench.json", "iterations.png")
RESULTS_PAGE = ("results.json", "results.md")


def write_sweep_spec(out: str | Path, spec: dict) -> Path:
    """sweep_spec.json: what the sweep in ``out`` is (task, --set, --config, --smoke, its
    parameters); a rerun there must match it."""

    def write(stage: Path) -> dict:
        atomic_write(stage / SWEEP_SPEC, json.dumps(spec, indent=1))
        return spec

    write_set(out, [SWEEP_SPEC], write)
    return Path(out) / SWEEP_SPEC


def write_sweep_tables(
    out: str | Path, columns: list[str], rows: list[dict], doc: dict, log: str | None
) -> dict:
    """sweep.csv (``rows`` under ``columns`` and ``id``; None as an empty cell), sweep.json
    (``doc``) and computed.log (``log``, one line per point computed by any run; none while
    no run has computed one), as one set; returns ``doc``."""

    def write(stage: Path) -> dict:
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=columns + ["id"], extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in columns + ["id"]})
        atomic_write(stage / SWEEP_TABLES[0], buf.getvalue())
        atomic_write(stage / SWEEP_TABLES[1], json.dumps(json_safe(doc), indent=1))
        if log is not None:
            atomic_write(stage / COMPUTED_LOG, log)
        return doc

    return write_set(out, [*SWEEP_TABLES, COMPUTED_LOG], write)


def write_sweep_plots(out: str | Path, draw: Callable[[Path], list[str]]) -> list[str]:
    """The sweep's plots: ``draw(directory)`` draws them there and returns their names; they
    replace the files of those names in ``out`` (a plot not drawn this time stays as it was).
    Returns the names."""

    def write(stage: Path) -> dict:
        return {"wrote": draw(stage)}

    return write_set(out, [], write)["wrote"]


def write_robustness(out: str | Path, report: dict) -> Path:
    """robustness.json: the report of ``hydroilqr robustness``."""

    def write(stage: Path) -> dict:
        atomic_write(stage / ROBUSTNESS, json.dumps(report, indent=1) + "\n")
        return report

    write_set(out, [ROBUSTNESS], write)
    return Path(out) / ROBUSTNESS


def write_bench(out: str | Path, doc: dict, draw: Callable[[Path], None]) -> dict:
    """bench.json (``doc``) and iterations.png (``draw(path)`` draws it); returns ``doc``."""

    def write(stage: Path) -> dict:
        atomic_write(stage / BENCH_FILES[0], json.dumps(doc, indent=1))
        draw(stage / BENCH_FILES[1])
        return doc

    return write_set(out, list(BENCH_FILES), write)


def write_results_page(out: str | Path, page: dict, markdown: str) -> dict[str, Path]:
    """results.json (``page``) and results.md (``markdown``) in ``out``; their paths, by
    format."""

    def write(stage: Path) -> dict:
        atomic_write(stage / RESULTS_PAGE[0], json.dumps(page, indent=1) + "\n")
        atomic_write(stage / RESULTS_PAGE[1], markdown)
        return page

    write_set(out, list(RESULTS_PAGE), write)
    return {"json": Path(out) / RESULTS_PAGE[0], "md": Path(out) / RESULTS_PAGE[1]}
