"""The generated results page (``hydroilqr results``), smoke-sized."""

from __future__ import annotations

import json

from hydroilqr import cli
from hydroilqr.studies import results


def test_results_page_smoke(tmp_path):
    paths = results.generate(["cartpole-wall"], out=tmp_path, smoke=True)
    md = (tmp_path / "results.md").read_text()
    assert paths["md"] == tmp_path / "results.md"
    assert f"hydroilqr results cartpole-wall --smoke --out {tmp_path}" in md
    row = next(ln for ln in md.splitlines() if ln.startswith("| `cartpole-wall`"))
    assert "angle err rad" in row
    page = json.loads((tmp_path / "results.json").read_text())
    assert page["smoke"] is True
    assert page["environment"]["drake"]
    (solved,) = page["sections"]["solves"]
    assert solved["task"] == "cartpole-wall" and solved["iterations"] >= 1
    assert "final_angle_error_rad" in solved["metrics"]


def test_results_command(tmp_path, capsys):
    out = tmp_path / "page"
    rc = cli.main(["results", "cartpole-wall", "--smoke", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    assert "wrote" in capsys.readouterr().out
    md = (out / "results.md").read_text()
    assert f"hydroilqr results cartpole-wall --smoke --out {out}" in md
    json.loads((out / "results.json").read_text())


def test_results_page_has_goal_status_transfer_and_bench_sections(tmp_path):
    bench = {
        "environment": {"command": "hydroilqr bench kinova-forward", "load_average": 0.4},
        "tasks": {
            "kinova-forward": {
                "task": "kinova-forward",
                "paper": {"median_s": 0.52, "final_cost": 43.9},
                "fast": {"median_s": 0.38, "final_cost": 44.3},
                "paper_same_solver": {"median_s": 0.53, "final_cost": 44.3},
                "speedup_median": 1.4,
                "speedup_same_solver_median": 1.4,
                "speedup_same_solver_total": 1.6,
                "cost_rel_diff_same_solver": 0.0003,
                "limits": {"limit_s": 0.11, "fast_share_of_limit": 0.3},
            }
        },
    }
    (tmp_path / "bench").mkdir()
    (tmp_path / "bench" / "bench.json").write_text(json.dumps(bench))
    results.generate(["kinova-forward"], out=tmp_path, smoke=True)
    md = (tmp_path / "results.md").read_text()
    page = json.loads((tmp_path / "results.json").read_text())
    (solved,) = page["sections"]["solves"]
    assert solved["status"] and solved["goal"]["checks"][0]["metric"] == "target_error_m"
    (moved,) = page["sections"]["transfer"]
    assert moved["task"] == "kinova-forward" and moved["final_gap_m"] >= 0
    assert "## Transfer (open-loop playback)" in md and "## Speed per iteration" in md
    # one row per mismatch case of the task file, each played on its changed "real" system
    cases = page["sections"]["mismatch"]
    assert [c["case"] for c in cases] == ["friction-30", "friction+30", "mass-20", "mass+20"]
    assert cases[0]["truth_overrides"] == ["ball.friction=0.14"]
    assert cases[2]["truth_overrides"][0].endswith("kinova_gen3/ball_light.sdf")
    assert all(c["resting_gap"] >= 0 and c["unit"] == "m" for c in cases)
    assert "## Transfer under model mismatch" in md and "| `kinova-forward` | `mass+20` |" in md
    row = next(ln for ln in md.splitlines() if "| `friction-30` |" in ln)
    assert row.split("|")[3].strip().endswith(" cm")
    assert "| `kinova-forward` | 0.520 | 0.530 | 0.380 | 1.4x | 1.4x | 1.6x |" in md
    assert "(load 0.4)" in md


def test_gait_report_section_links_the_gait_diagram(tmp_path):
    """Issue 37: the cheetah tasks get a "Gaits" table (duty, stance slip, overlaps, phase,
    stride frequency, cost of transport) whose rows link their gait.png, written beside the
    page."""
    from types import SimpleNamespace

    import numpy as np

    from hydroilqr import Task, metrics

    task = Task.load("cheetah-trot-1.0", smoke=True)
    U = task.initial_guess(task.steps)
    X = task.dynamics.rollout(task.x0, U)
    K = np.zeros((len(U), U.shape[1], X.shape[1]))
    sol = SimpleNamespace(t=task.dynamics.dt * np.arange(len(X)), X=X, U=U, K=K, extra={})
    r = results.TaskResult("cheetah-trot-1.0", task, sol, metrics.compute(task, sol), 1.0)
    ctx = results.Context(command="hydroilqr results", smoke=True, out=str(tmp_path))
    loop = tmp_path / "mpc" / "cheetah-trot-1.0"  # a closed loop run into the results dir
    loop.mkdir(parents=True)
    (loop / "mpc.json").write_text(json.dumps({"planner": "sampling", "metrics": r.metrics}))
    (section,) = results.metric_reports([r], ctx)
    assert section.title == "Gaits" and "stance slip m/s" in section.markdown
    assert "[gait.png](results/cheetah-trot-1.0/gait.png)" in section.markdown
    # issue 52 item 3: the plan, its playback and the closed loop, each a row
    motions = [row["motion"] for row in section.data]
    assert motions == ["plan", "playback", "closed loop (sampling)"]
    plan, played, looped = section.data
    assert looped["v m/s"] == plan["v m/s"] != "-" and played["v m/s"] != "-"
    assert (tmp_path / "results" / "cheetah-trot-1.0" / "gait.png").exists()
    assert results.metric_reports([], ctx) == []


def test_results_is_dated_estimated_and_leaves_the_repositorys_page_alone(tmp_path):
    """Issue 54, item 11: the page carries its date and wall time; an estimate from the
    shipped page; the default --out is not docs/."""
    import argparse
    from datetime import datetime

    from hydroilqr.cli import results as cli_results

    results.generate(["cartpole-wall"], out=tmp_path, smoke=True)
    page = json.loads((tmp_path / "results.json").read_text())
    assert datetime.fromisoformat(page["environment"]["date"]).tzinfo is not None
    assert page["wall_seconds"] > 0
    assert f"date {page['environment']['date']}" in (tmp_path / "results.md").read_text()
    page["sections"]["solves"][0]["solve_seconds"] = 120.0
    (tmp_path / "results.json").write_text(json.dumps(page))
    said = results.estimate(["cartpole-wall"], False, tmp_path / "results.json")
    assert said.startswith(f"about {page['wall_seconds']:.0f} s") or "2 min" in said
    assert "2 min" in results.estimate(["cartpole-wall", "x"], False, tmp_path / "results.json")
    assert results.estimate(["cartpole-wall"], False, tmp_path / "none.json") == ""
    p = argparse.ArgumentParser()
    cli_results.setup(p)
    assert p.parse_args([]).out == "runs/results"


def test_each_robustness_part_names_its_python_and_drake(tmp_path):
    """The results page puts robustness runs of several stacks side by side (issue 55): each
    part's line says which Python and Drake ran it, from its own robustness.json."""
    from pathlib import Path

    from hydroilqr.studies.results import Context, robustness_table

    src = Path(__file__).resolve().parents[2] / "docs" / "robustness" / "finger-spin"
    doc = json.loads((src / "robustness.json").read_text())
    for name, (python, drake) in {"a": ("3.11.7", "1.51.1"), "b": ("3.12.1", "1.56.0")}.items():
        (tmp_path / "robustness" / name).mkdir(parents=True)
        doc["environment"].update(python=python, drake=drake)
        (tmp_path / "robustness" / name / "robustness.json").write_text(json.dumps(doc))
    context = Context(command="hydroilqr results", smoke=False, out=str(tmp_path))
    text = robustness_table([], context).markdown
    assert "Python 3.11.7, Drake 1.51.1" in text and "Python 3.12.1, Drake 1.56.0" in text


def test_a_record_says_what_was_removed_from_it(tmp_path):
    """A record edited after its run (a superseded task's entries taken out, its ``removed``
    saying which and why) is read as any other, and its line names what went."""
    from pathlib import Path

    from hydroilqr.studies.results import Context, robustness_table

    src = Path(__file__).resolve().parents[2] / "docs" / "robustness" / "finger-spin"
    doc = json.loads((src / "robustness.json").read_text())
    doc["removed"] = {"kinova-up": "superseded"}
    (tmp_path / "robustness" / "a").mkdir(parents=True)
    (tmp_path / "robustness" / "a" / "robustness.json").write_text(json.dumps(doc))
    context = Context(command="hydroilqr results", smoke=False, out=str(tmp_path))
    text = robustness_table([], context).markdown
    assert "Since removed: `kinova-up` (superseded)." in text
    assert "| `finger-spin` | solve |" in text and "| `kinova-up` |" not in text


def test_the_search_section_puts_ilqr_alone_beside_search_and_polish(tmp_path):
    """A task with a ``robustness --search`` record: its pass rate beside iLQR alone's, per
    kernel set, with the median run time; the throughput records' samples per second with
    each number of workers. No search record: no section."""
    from hydroilqr.studies.results import Context, kernel_table, search_table

    def record(met: int, search: bool, blas: str, seconds=(10.0, 30.0, 20.0)) -> dict:
        runs = [{"index": i, "seconds": s} for i, s in enumerate(seconds, 1)]
        task = {"task": "p", "goal_declared": True, "goal_met": met, "runs": 10, "results": runs}
        doc = {"tasks": [task], "environment": {"blas_core": blas}, "noise": 1e-9, "runs": 10}
        return {**doc, **({"search": True} if search else {})}

    def put(name: str, doc: dict, kind: str = "robustness") -> None:
        (tmp_path / kind / name).mkdir(parents=True)
        (
            tmp_path / kind / name / f"{kind if kind == 'robustness' else 'throughput'}.json"
        ).write_text(json.dumps(doc))

    context = Context(command="hydroilqr results", smoke=False, out=str(tmp_path))
    put("p", record(2, False, "Haswell"))
    assert search_table([], context) is None
    put("p-search", record(9, True, "Haswell"))
    put("p-search-skylakex", record(10, True, "SkylakeX"))
    rows = [
        {"workers": n, "samples_per_second": sps, "batch_overhead_seconds": 0.01,
         "cpu_share": 0.5}
        for n, sps in ((1, 100.0), (2, 170.0))
    ]  # fmt: skip
    put("p", {"task": "p", "rows": rows, "environment": {"blas_core": "Haswell"}}, "search")
    md = search_table([], context).markdown
    assert "| `p` | Haswell | 2 of 10 | 9 of 10 | 20 |" in md
    assert "| `p` | SkylakeX | - | 10 of 10 | 20 |" in md
    assert "| `p` | 2 | 170.0 | 1.70x | 10 | 50% |" in md
    docs = [json.loads(p.read_text()) for p in sorted(tmp_path.glob("robustness/*/*.json"))]
    assert "| `p` | search + polish | 0 | 9 of 10 |" in kernel_table(docs)
