"""Receding-horizon search (issue 51 item 3): windows, the shifted warm start, and a stitched
command whose rollout from the start is the windows' rollouts end to end."""

import numpy as np
import pytest

from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.load import load_task
from hydroilqr.problem.search import SearchConfig
from hydroilqr.solver import search, splines


def test_windows_cover_the_horizon_and_keep_their_shift():
    for N, W, S in ((30, 10, 5), (31, 10, 4), (10, 10, 3), (7, 3, 3)):
        ws = search.windows(N, W, S)
        assert ws[0][0] == 0 and sum(k for _, _, k in ws) == N
        for (s, steps, kept), nxt in zip(ws, ws[1:]):
            assert nxt[0] == s + kept and kept == S and steps == W
        s, steps, kept = ws[-1]
        assert s + steps == N and kept == steps  # the last window keeps all it has


@pytest.mark.parametrize("order", [1, 3])
def test_a_shifted_spline_continues_the_old_one(order):
    """Shifted by whole knot spacings, the warm start's knots are the old spline's values
    there: the spline seen from a later start."""

    class Space:
        def __init__(self, K, T):
            self.K, self.T, self.settings = K, T, SearchConfig(order=order)
            self.lower, self.upper = -np.inf, np.inf

    rng = np.random.default_rng(0)
    old, new = Space(6, 1.0), Space(6, 1.0)
    knots = rng.standard_normal((6, 2))
    out = search.shifted_knots(old, knots, new, 0.4)  # two spacings of 0.2
    assert np.allclose(out[:4], knots[2:])
    assert np.allclose(out[4:], knots[-1])  # past the old end: its last value holds
    t = splines.knot_times(6, 1.0, order)
    assert np.allclose(out, splines.evaluate(knots, t + 0.4, 1.0, order))


@pytest.fixture(scope="module", params=["position", "torque"])
def cartpole(request):
    from hydroilqr.model.task import Task

    sets = ["num_steps=24", f"search.space={request.param}", "search.samples=6",
            "search.iterations=3", "search.knots=4", "search.window_steps=10",
            "search.shift_steps=5"]  # fmt: skip
    return Task.load("cartpole-wall", sets)


def test_a_receding_search_stitches_its_windows(cartpole):
    """Windows of 10 steps shifted by 5 over 24: each window searched from the state the
    kept steps reach; the stitched command's rollout from the start passes through every
    window's start state (bit for bit) and its cost is the task's cost of it; no window ends
    above the cost of its warm start; in position space each window's first knot is the
    target the command reached."""
    seen = []
    space, res = search.run_search(cartpole, on_window=lambda w: seen.append(w) and False)
    N = cartpole.steps
    assert [w["start"] for w in res.windows] == [0, 5, 10, 15]
    assert [w["window"] for w in seen] == [0, 1, 2, 3]
    cmd = res.best.command
    pos = cartpole.config.search.space == "position"
    assert cmd.shape == (N + 1 if pos else N, cartpole.dynamics.nu)
    r = space.rollout(cartpole, cmd)
    assert res.best.cost == r.cost == pytest.approx(cartpole.cost.total(r.X, r.U))
    for w in range(4):  # each window's start state is the stitched rollout's
        hist = [h for h in res.history if h["window"] == w]
        assert len(hist) == 3 and hist[-1]["best_cost"] <= res.costs[3 * w, 0]
    x, pin = cartpole.x0, None
    for w in res.windows:  # replaying the windows: the same states
        sp = search.SearchSpace(cartpole, cartpole.config.search, w["start"], w["steps"], x, pin)
        assert np.array_equal(sp.x0, r.X[w["start"]])
        if pos:
            assert np.array_equal(sp.lower[0], cmd[w["start"]])
        x = r.X[w["start"] + w["kept"]]
        pin = cmd[w["start"] + w["kept"]] if pos else None
    assert res.samples == 4 * 3 * 6


def test_a_receding_search_is_seeded():
    from hydroilqr.model.task import Task

    sets = ["num_steps=12", "search.samples=4", "search.iterations=2", "search.knots=3",
            "search.window_steps=6", "search.shift_steps=3", "search.space=position"]  # fmt: skip
    a = search.run_search(Task.load("cartpole-wall", sets))[1]
    b = search.run_search(Task.load("cartpole-wall", sets))[1]
    c = search.run_search(Task.load("cartpole-wall", [*sets, "search.seed=1"]))[1]
    assert np.array_equal(a.costs, b.costs) and np.array_equal(a.best.command, b.best.command)
    assert not np.array_equal(a.costs, c.costs)


def test_window_settings_are_refused_in_one_line():
    for bad, key in (
        ("search.window_steps=-1", "search.window_steps"),
        ("search.shift_steps=20", "search.shift_steps"),
        ("search.knots=12", "search.knots"),
    ):
        with pytest.raises(ConfigError, match=key):
            load_task("cartpole-wall", ["search.window_steps=10", bad])
