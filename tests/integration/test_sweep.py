"""`hydroilqr sweep`: value parsing, a 3-point sweep on the embedded Dask cluster, resume."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from hydroilqr.cli import main
from hydroilqr.problem.errors import ConfigError
from hydroilqr.studies.sweep import POINT_COLUMNS, grid, parse_values, point_id, run_sweep

KEY = "tip.hydroelastic_modulus"


TINY = ["num_steps=5", "solver.max_iterations=1"]


# Tiny cart-pole-wall solves: 30 steps, 3 iterations (contact happens within 0.3 s).
SMALL = ["num_steps=30", "solver.max_iterations=3"]


def _rows(out: Path) -> list[dict]:
    with open(out / "sweep.csv") as f:
        return list(csv.DictReader(f))


def _log(out: Path) -> list[str]:
    return [ln.split("\t")[0] for ln in (out / "computed.log").read_text().splitlines()]


@pytest.fixture(scope="module")
def swept(tmp_path_factory, dask_scheduler):
    """One 3-point sweep through the CLI on the tests' shared cluster (tests/conftest.py);
    the middle point is invalid (negative modulus)."""
    out = tmp_path_factory.mktemp("sweep")
    argv = [
        "sweep",
        "cartpole-wall",
        "--smoke",
        "--param",
        KEY,
        "--values",
        "1e3,-5,1e6",
        "--scheduler",
        dask_scheduler,
        "--connect-timeout",  # (the address and its deadline as studies.cluster.Scheduler)
        "120",
        "--out",
        str(out),
    ]
    for s in SMALL:
        argv += ["--set", s]
    assert main(argv) == 1  # one point failed: the table is written, the exit code says so
    return out, argv


def test_sweep_refuses_bad_specs_before_starting(tmp_path):
    from hydroilqr.problem.errors import ConfigError
    from hydroilqr.studies.sweep import run_sweep

    with pytest.raises(ConfigError, match="at most two"):
        run_sweep("cartpole-wall", [("a", [1]), ("b", [1]), ("c", [1])], tmp_path / "a")
    with pytest.raises(ConfigError, match="the same key twice"):
        run_sweep("cartpole-wall", [(KEY, [1e6]), (KEY, [2e6])], tmp_path / "b")
    # The last point is built before the cluster starts, like the first.
    with pytest.raises(ConfigError, match="must be positive"):
        run_sweep("cartpole-wall", [(KEY, [1e6, -5.0])], tmp_path / "c", sets=TINY)
    assert not (tmp_path / "c" / "points").exists()


def test_sweep_retry_failed_and_a_different_param_in_the_same_directory(tmp_path, dask_scheduler):
    import json

    from hydroilqr.problem.errors import ConfigError
    from hydroilqr.studies.sweep import point_id, run_sweep

    out = tmp_path / "s"
    (out / "points").mkdir(parents=True)
    pid = point_id({KEY: 1e6})
    failed = {"id": pid, f"param:{KEY}": 1e6, "status": "failed", "error": "KilledWorker: x"}
    (out / "points" / f"{pid}.json").write_text(json.dumps(failed))
    # A spec written before solver.threads=1 stopped being listed under --set: the same sweep.
    spec = {
        "task": "cartpole-wall",
        "config_file": None,
        "smoke": False,
        "set": sorted(TINY + ["solver.threads=1"]),
        "params": [{"key": KEY, "values": [1e6]}],
    }
    (out / "sweep_spec.json").write_text(json.dumps(spec))  # fmt: skip
    res = run_sweep("cartpole-wall", [(KEY, [1e6])], out, sets=TINY, plots=False)
    assert res["computed"] == 0 and res["failed"] == 1  # kept as it is
    # Another swept key over the same values is another sweep.
    with pytest.raises(ConfigError, match="--param"):
        run_sweep("cartpole-wall", [("tip.dissipation", [1e6])], out, sets=TINY, plots=False)
    again = {"sets": TINY, "plots": False, "retry_failed": True, "scheduler": dask_scheduler}
    res = run_sweep("cartpole-wall", [(KEY, [1e6])], out, **again)
    assert res["computed"] == 1 and res["failed"] == 0
    assert json.loads((out / "points" / f"{pid}.json").read_text())["status"] == "ok"


def test_parse_values():
    assert parse_values("logspace:1e3:1e9:13")[:3] == [1000.0, 3162.27766017, 10000.0]
    assert parse_values("logspace:1e3:1e9:13")[-1] == 1e9
    assert parse_values("linspace:0:1:3") == [0.0, 0.5, 1.0]
    assert parse_values("1, 2.5,3e4") == [1, 2.5, 30000.0]
    for bad in ("logspace:0:1:3", "logspace:1:2", "a,b", "linspace:0:1:0", "1,1"):
        with pytest.raises(ConfigError):
            parse_values(bad)
    # a generated list that repeats a value would compute one point several times
    for bad in ("linspace:1:1:3", "logspace:1e5:1e5:2", "logspace:1:1.0000000000001:3"):
        with pytest.raises(ConfigError, match="repeated values"):
            parse_values(bad)
    assert parse_values("linspace:5:5:1") == [5.0]
    with pytest.raises(ConfigError, match="at most 10000 points"):
        parse_values("linspace:0:1:100000000000")  # refused before numpy allocates it
    g = grid([("a", [1, 2]), ("b", [3, 4, 5])])
    assert len(g) == 6 and g[0] == {"a": 1, "b": 3} and g[-1] == {"a": 2, "b": 5}
    assert point_id({KEY: 1000.0}) == point_id({KEY: 1000.0}) != point_id({KEY: 1000.5})
    assert point_id({KEY: 1000000}) == point_id({KEY: 1e6})  # one value, two spellings


def test_three_point_sweep(swept):
    out, _ = swept
    rows = _rows(out)
    assert [float(r[KEY]) for r in rows] == [-5.0, 1000.0, 1e6]  # sorted by value
    for col in POINT_COLUMNS:
        assert col in rows[0]
    assert "max_contact_faces" in rows[0]  # the task's other scalar metrics are columns too
    # and named scalars one level down: the final error per Qf block, the cost terms
    assert any(c.startswith("final_error.") for c in rows[0])
    assert any(c.startswith("cost_terms.") for c in rows[0])
    ok = [r for r in rows if r["status"] == "ok"]
    assert len(ok) == 2
    for r in ok:
        assert float(r["final_cost"]) > 0 and "max_overlap_m" in r
        assert int(r["iterations"]) <= 3 and float(r["wall_seconds"]) > 0
    bad = rows[0]
    assert bad["status"] == "failed" and "must be positive" in bad["error"]
    doc = json.loads((out / "sweep.json").read_text())
    assert doc["summary"] == {"points": 3, "done": 2, "failed": 1, "missing": 0}
    assert len(list((out / "points").glob("*.json"))) == 3
    assert len(list((out / "points").glob("*.npz"))) == 2  # trajectories of the solved ones
    for f in ("sweep.png", "snapshots.png"):
        assert (out / f).stat().st_size > 10_000
    assert sorted(_log(out)) == sorted(r["id"] for r in rows)


def test_resume_computes_only_missing(swept):
    out, argv = swept
    before = {r["id"]: r for r in _rows(out)}
    victim = next(i for i, r in before.items() if r["status"] == "ok")
    (out / "points" / f"{victim}.json").unlink()  # as if killed before it finished
    (out / "points" / f".{victim}.json.123.tmp").write_text("{torn")  # a torn temp file
    n_log = len(_log(out))
    assert main(argv) == 1  # the failed point is kept, and still reported
    new = _log(out)[n_log:]
    assert new == [victim]  # only the missing point was computed; the failed one is kept
    after = {r["id"]: r for r in _rows(out)}
    assert after.keys() == before.keys()
    for i, r in after.items():
        assert r["status"] == before[i]["status"]
        if r["status"] == "ok":  # deterministic solves: same table
            assert float(r["final_cost"]) == pytest.approx(float(before[i]["final_cost"]))
    # Nothing missing: no cluster is started and nothing is computed.
    res = run_sweep("cartpole-wall", [(KEY, [1e3, -5, 1e6])], out, sets=SMALL, smoke=True)
    assert res["computed"] == 0 and res["skipped"] == 3 and res["failed"] == 1
    # A different sweep in the same directory is refused.
    with pytest.raises(ConfigError, match=r"--set \['num_steps=30', 'solver.max_iterations=3'\]"):
        run_sweep("cartpole-wall", [(KEY, [1e3])], out, sets=["num_steps=20"], smoke=True)
    # The same sweep on a subset computes nothing and keeps the other points in the table.
    res = run_sweep("cartpole-wall", [(KEY, [1e6])], out, sets=SMALL, smoke=True)
    assert res["computed"] == 0 and res["failed"] == 0
    assert sorted(r["id"] for r in _rows(out)) == sorted(before)
    summary = json.loads((out / "sweep.json").read_text())["summary"]
    assert summary == {"points": 3, "done": 2, "failed": 1, "missing": 0}
    # A torn spec cannot vouch for the points: refused, not overwritten.
    spec = (out / "sweep_spec.json").read_text()
    (out / "sweep_spec.json").write_text("{bad")
    with pytest.raises(ConfigError, match="sweep_spec.json is unreadable"):
        run_sweep("cartpole-wall", [(KEY, [1e6])], out, sets=["num_steps=20"], smoke=True)
    (out / "sweep_spec.json").write_text(spec)


def test_negative_values_after_values_flag():
    from hydroilqr.cli import _join_negative_values

    argv = ["sweep", "t", "--param", "k", "--values", "-5,1e6", "--param", "j", "--values", "1,2"]
    assert _join_negative_values(argv)[4:6] == ["--values=-5,1e6", "--param"]
    assert _join_negative_values(argv)[-2:] == ["--values", "1,2"]


def test_sweep_plot_legend_names_markers_of_any_series(tmp_path, monkeypatch):
    import matplotlib.figure

    from hydroilqr.studies.sweep import plot_sweep

    legends = []
    real = matplotlib.figure.Figure.savefig

    def spy(fig, *args, **kwargs):
        for ax in fig.axes:
            if ax.get_legend() is not None:
                legends.append([t.get_text() for t in ax.get_legend().get_texts()])
        return real(fig, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", spy)
    a, b = "tip.hydroelastic_modulus", "solver.regularization_min"

    def row(x, y, **kw):
        base = {f"param:{a}": x, f"param:{b}": y, "status": "ok", "final_cost": 1.0 + x / 10}
        base.update({"max_overlap_m": 0.001, "tunnelled": False, "converged": True})
        return {**base, **kw}

    rows = [row(1.0, 0.1), row(2.0, 0.1), row(1.0, 0.2, tunnelled=True)]
    rows += [row(2.0, 0.2, converged=False), row(3.0, 0.2, status="failed")]
    plot_sweep(tmp_path / "s.png", "t", [a, b], rows, [[1.0, 2.0, 3.0], [0.1, 0.2]])
    names = set().union(*map(set, legends))
    assert {"tunnelled", "not converged", "failed"} <= names


def test_points_the_scheduler_lost_stay_missing_and_set_paths_are_absolute(tmp_path, monkeypatch):
    """A lost scheduler (futures cancelled) leaves its points missing, so a plain rerun
    computes them, and says so in one line; relative paths in --set are made absolute on the
    client (remote workers run elsewhere)."""
    from concurrent.futures import CancelledError

    from hydroilqr.problem.errors import ConfigError
    from hydroilqr.studies import sweep as sweep_mod

    class Lost:
        def result(self):
            raise CancelledError("scheduler-connection-lost")

    class FakeClient:
        def submit(self, *a, **k):
            return Lost()

        def subscribe_topic(self, *a, **k):
            pass

        def unsubscribe_topic(self, *a, **k):
            pass

        def nthreads(self):
            return {"w": 1}

        def close(self):
            pass

    monkeypatch.setattr(sweep_mod, "open_client", lambda s, w: (FakeClient(), None))
    monkeypatch.setattr(sweep_mod, "as_completed", lambda futs: list(futs))
    out = tmp_path / "sw"
    with pytest.raises(ConfigError, match="2 point"):
        sweep_mod.run_sweep("cartpole-wall", [(KEY, [1e5, 1e6])], out, sets=SMALL, plots=False)
    assert not list((out / "points").glob("*.json"))  # missing, not failed
    monkeypatch.chdir(tmp_path)
    (tmp_path / "U.csv").write_text("0\n" * 400)
    with pytest.raises(ConfigError):
        sweep_mod.run_sweep(
            "cartpole-wall",
            [(KEY, [1e5])],
            tmp_path / "sw2",
            sets=[*SMALL, "initial_guess=U.csv"],
            plots=False,
        )
    spec = json.loads((tmp_path / "sw2" / "sweep_spec.json").read_text())
    assert f"initial_guess={tmp_path / 'U.csv'}" in spec["set"]


def test_a_sweep_recorded_with_a_relative_set_path_still_resumes(
    tmp_path, monkeypatch, dask_scheduler
):
    """Older sweep_spec.json files kept a relative path in --set as given; this version records
    it absolute, and still recognises the older sweep as the same one."""
    from hydroilqr.studies import sweep as sweep_mod

    monkeypatch.chdir(tmp_path)
    (tmp_path / "pm").mkdir()
    out = tmp_path / "sw"
    sets = [*SMALL, "package_map.foo=pm"]
    res = sweep_mod.run_sweep(
        "cartpole-wall", [(KEY, [1e6])], out, sets=sets, plots=False, scheduler=dask_scheduler
    )
    assert res["computed"] == 1
    spec = json.loads((out / "sweep_spec.json").read_text())
    spec["set"] = sorted(
        v if not v.startswith("package_map") else "package_map.foo=pm" for v in spec["set"]
    )
    (out / "sweep_spec.json").write_text(json.dumps(spec))  # as an older version wrote it
    res = sweep_mod.run_sweep(
        "cartpole-wall", [(KEY, [1e6])], out, sets=sets, plots=False, scheduler=dask_scheduler
    )
    assert res["computed"] == 0


def test_a_key_that_is_not_numeric_is_refused_before_any_work(tmp_path):
    # `name` takes a number as text: every point would be the same task
    for key, vals in (("name", [1]), ("description", [1, 2])):
        with pytest.raises(ConfigError, match=f"--param {key}: not a numeric task key"):
            run_sweep("cartpole-wall", [(key, vals)], tmp_path / "s", smoke=True)
    assert not (tmp_path / "s").exists()
    # a shorthand that creates the geometry entry it sets is numeric all the same
    from hydroilqr.studies.sweep import check_numeric_params

    check_numeric_params("kinova-forward", {}, None, True, [("ball.friction", [0.3])])


def test_a_grid_of_too_many_points_is_refused_before_any_solve(tmp_path):
    vals = ",".join(str(i) for i in range(1, 201))  # 200 x 200 = 40000 points
    with pytest.raises(ConfigError, match="40000 points; at most 10000"):
        run_sweep(
            "cartpole-wall",
            [
                ("tip.hydroelastic_modulus", parse_values(vals)),
                ("solver.max_iterations", parse_values(vals)),
            ],
            tmp_path / "o",
            smoke=True,
        )
    assert not (tmp_path / "o" / "points").exists()
