"""The hopper's closed loop with cheap updates (examples/hopper-mpc-hop.yaml, issue 52): lock-step
with one control period's latency, as an idle machine's --realtime run executes it while every
update fits its period (mpc.lockstep_latency)."""

from pathlib import Path

import pytest

from hydroilqr.studies.robustness import loop_run

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "hopper-mpc-hop.yaml"


def _ref(*overrides: str) -> dict:
    return {
        "label": "hopper-mpc-hop",
        "name": str(EXAMPLE),
        "overrides": ["mpc.lockstep_latency=0.04", *overrides],
        "config": None,
        "smoke": False,
    }


@pytest.mark.slow  # three full-size closed loops, each from the built-in's offline solve
def test_hopper_hop_loop_meets_its_goal_across_perturbed_runs():
    """Two loops whose first plans start from the guess perturbed by a relative 1e-9 (runs 1
    and 2 of `hydroilqr robustness --mpc`), and one on a simulated hopper whose ground has
    less friction (0.7 for 1.0): each hops forward by the task's goal. A property of the runs, not
    one basin's numbers (which basin a run lands in is a last-bit matter)."""
    runs = [loop_run(_ref(), k, 0, 1e-9) for k in (1, 2)]
    runs.append(loop_run(_ref("mpc.truth_overrides=[ground.friction=0.7]"), 1, 0, 1e-9))
    assert [r.status for r in runs] == ["ran"] * 3, [r.record() for r in runs]
    assert all(r.goal_met for r in runs), [r.record() for r in runs]
