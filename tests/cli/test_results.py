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
