"""bench: the paper method vs the fast configuration, alternating in one process (smoke)."""

import json

from hydroilqr.cli import main


def test_bench_smoke_writes_json_and_plot(tmp_path):
    out = tmp_path / "bench"
    rc = main(["bench", "cartpole-wall", "--smoke", "--iterations", "2", "--fast",
               "solver.derivatives=forward", "--out", str(out)])
    assert rc == 0
    doc = json.loads((out / "bench.json").read_text())
    assert (out / "iterations.png").stat().st_size > 0
    for key in ("iterations", "threads", "paper", "fast", "tasks"):
        assert key in doc
    r = doc["tasks"]["cartpole-wall"]
    for key in ("speedup_median", "cost_rel_diff", "initial_polygons", "accuracy", "threads"):
        assert key in r, key
    for method in ("paper", "fast"):
        m = r[method]
        assert 1 <= m["iterations"] <= 2
        assert m["p10_s"] <= m["median_s"] <= m["p90_s"]
        assert set(m["phase_share"]) == {"rollout", "derivatives", "backward_pass",
                                         "line_search"}
        assert abs(sum(m["phase_share"].values()) - 1.0) < 1e-9
        assert m["final_cost"] <= m["initial_cost"]
        assert "max_faces" in m["polygons"]
    assert "tamsi" in " ".join(r["configs"]["paper"])
    # Exact derivative modes agree with AutoDiff where AutoDiff is exact.
    acc = r["accuracy"]
    assert acc["central"]["max"]["free"] < 1e-4
    assert acc["central"]["max"].get("compliant-rigid", 0.0) < 1e-4
    assert set(r["threads"]["seconds"]) >= {"1"}
