"""The sampling search: splines, colored noise, each method against a known optimum,
seeding, the PD+ law shared with playback, the search settings' refusals, Dask workers."""

import dataclasses
import math
import time

import numpy as np
import pytest

from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.load import load_task
from hydroilqr.problem.search import SearchConfig
from hydroilqr.solver import sampling, splines

# ---------------------------------------------------------------------------- splines


@pytest.mark.parametrize("order", [0, 1, 3])
def test_a_spline_passes_through_its_knots(order):
    rng = np.random.default_rng(1)
    K, T = 6, 1.2
    knots = rng.standard_normal((K, 2))
    t = splines.knot_times(K, T, order)
    assert np.allclose(splines.evaluate(knots, t, T, order), knots)


def test_spline_orders_between_the_knots():
    T, knots = 1.0, np.array([[0.0], [1.0], [4.0], [9.0]])  # at t = 0, 1/3, 2/3, 1 (orders 1, 3)
    t = np.linspace(0, T, 61)
    zero = splines.evaluate(knots, t, T, 0)
    assert set(np.unique(zero)) <= {0.0, 1.0, 4.0, 9.0}  # held values
    assert zero[np.searchsorted(t, 0.3)][0] == 1.0  # knot 1 holds on [1/4, 1/2)
    linear = splines.evaluate(knots, [1 / 6], T, 1)
    assert linear[0, 0] == pytest.approx(0.5)  # halfway between knots 0 and 1
    # cubic: a linear function of t is reproduced exactly (finite-difference slopes)
    line = np.array([[0.0], [1.0], [2.0], [3.0]])
    assert np.allclose(splines.evaluate(line, t, T, 3)[:, 0], 3 * t)
    one = splines.evaluate(np.array([[2.5]]), t, T, 3)
    assert np.all(one == 2.5)  # one knot: a constant


def test_spline_basis_rows_sum_to_one():
    for order in (0, 1, 3):
        W = splines.basis(7, np.linspace(0, 2.0, 50), 2.0, order)
        assert np.allclose(W.sum(axis=1), 1.0)


# ---------------------------------------------------------------------------- noise


def test_colored_noise_has_unit_variance_and_correlates_neighbours():
    rng = np.random.default_rng(0)
    white = sampling.colored_noise(rng, 0.0, (4000, 8))
    red = sampling.colored_noise(rng, 2.0, (4000, 8))
    assert np.allclose(red.var(axis=0), 1.0, atol=0.1)
    assert abs(np.corrcoef(white[:, 2], white[:, 3])[0, 1]) < 0.1
    assert np.corrcoef(red[:, 2], red[:, 3])[0, 1] > 0.5  # temporally correlated


# ---------------------------------------------------------------------------- a known optimum

DT, N = 0.1, 30
A = np.array([[1.0, DT], [0.0, 1.0]])
B = np.array([0.0, DT])
X0 = np.array([1.0, 0.0])
Q, QF, R = np.diag([1.0, 0.1]), np.diag([100.0, 10.0]), 0.01


def _maps():
    """X_k = Phi_k x0 + Gam_k U for the double integrator."""
    Phi, Gam = np.zeros((N + 1, 2, 2)), np.zeros((N + 1, 2, N))
    Phi[0] = np.eye(2)
    for k in range(N):
        Phi[k + 1] = A @ Phi[k]
        Gam[k + 1] = A @ Gam[k]
        Gam[k + 1][:, k] += B
    return Phi, Gam


PHI, GAM = _maps()


def lq_cost(U) -> float:
    U = np.asarray(U, float).reshape(N)
    X = PHI @ X0 + GAM @ U
    return float(sum(X[k] @ Q @ X[k] for k in range(N)) + X[N] @ QF @ X[N] + R * U @ U)


def lq_optimum(W):
    """The least-squares optimum over knots θ with U = W θ, and its cost."""
    rows, rhs = [], []
    for k in range(N + 1):
        L = np.linalg.cholesky(QF if k == N else Q).T
        rows.append(L @ GAM[k] @ W)
        rhs.append(-L @ PHI[k] @ X0)
    rows.append(math.sqrt(R) * W)
    rhs.append(np.zeros(N))
    theta, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)
    return theta, lq_cost(W @ theta)


@pytest.mark.parametrize("method", sampling.METHODS)
@pytest.mark.parametrize("order", [0, 1, 3])
def test_each_method_approaches_the_least_squares_optimum(method, order):
    """A linear system with a quadratic cost over a spline of K knots: the optimum in knot
    space is a least-squares problem. Each sampler closes at least 95% of the gap between
    the nominal (zero controls) and that optimum."""
    K = 6
    W = splines.basis(K, DT * np.arange(N), N * DT, order)
    _, best = lq_optimum(W)
    start = lq_cost(np.zeros(N))
    cfg = SearchConfig(method=method, samples=32, iterations=60, knots=K, noise=1.0, elites=6)
    r = sampling.search(
        lambda cs: [lq_cost(c) for c in cs], lambda th: W @ th, np.zeros((K, 1)), np.ones(1), cfg
    )
    assert r.best.cost >= best - 1e-9  # no sample beats the optimum
    assert (r.best.cost - best) / (start - best) < 0.05
    assert np.all(np.diff(r.best_costs) <= 0)  # the best never gets worse
    assert r.costs.shape == (60, 32) and r.costs[0, 0] == start  # sample 0: the nominal


def test_the_same_seed_gives_the_same_samples_whatever_the_batches():
    W = splines.basis(5, DT * np.arange(N), N * DT, 1)
    cfg = SearchConfig(method="cem", samples=12, iterations=4, knots=5, noise=1.0, elites=3)
    seen = {}

    def batched(n):
        def evaluate(cs):
            seen.setdefault(n, []).extend(np.asarray(c).tobytes() for c in cs)
            out = []
            for part in np.array_split(np.arange(len(cs)), n):  # like n workers' batches
                out += [lq_cost(cs[i]) for i in part]
            return out

        return evaluate

    runs = [
        sampling.search(batched(n), lambda th: W @ th, np.zeros((5, 1)), np.ones(1), cfg)
        for n in (1, 3)
    ]
    assert seen[1] == seen[3]
    assert np.array_equal(runs[0].costs, runs[1].costs)
    assert np.array_equal(runs[0].best.knots, runs[1].best.knots)
    other = sampling.search(
        batched(1),
        lambda th: W @ th,
        np.zeros((5, 1)),
        np.ones(1),
        dataclasses.replace(cfg, seed=1),
    )
    assert not np.array_equal(other.costs, runs[0].costs)


def test_failed_rollouts_cost_inf_and_ctrl_c_keeps_the_best():
    W = splines.basis(4, DT * np.arange(N), N * DT, 1)
    cfg = SearchConfig(method="predictive", samples=8, iterations=50, knots=4, noise=1.0)
    calls = []

    def evaluate(cs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return [math.nan if i == 1 else lq_cost(c) for i, c in enumerate(cs)]

    r = sampling.search(evaluate, lambda th: W @ th, np.zeros((4, 1)), np.ones(1), cfg, keep=3)
    assert r.interrupted and len(r.history) == 2
    assert np.isinf(r.costs[:, 1]).all()
    assert len(r.candidates) == 3 and r.candidates[0] is r.best
    assert [c.cost for c in r.candidates] == sorted(c.cost for c in r.candidates)


def test_samples_stay_within_the_bounds():
    W = splines.basis(4, DT * np.arange(N), N * DT, 0)
    cfg = SearchConfig(method="mppi", samples=16, iterations=3, knots=4, noise=5.0)
    got = []

    def evaluate(cs):
        got.extend(cs)
        return [lq_cost(c) for c in cs]

    sampling.search(evaluate, lambda th: W @ th, np.zeros((4, 1)), np.ones(1), cfg, [-0.5], [0.5])
    assert np.abs(np.array(got)).max() <= 0.5


# ---------------------------------------------------------------------------- settings


@pytest.mark.parametrize(
    "override, words",
    [
        ("search.samples=1", "search.samples"),
        ("search.knots=0", "search.knots"),
        ("search.knots=100000", "search.knots"),
        ("search.method=random", "search.method"),
        ("search.space=velocity", "search.space"),
        ("search.order=2", "search.order"),
        ("search.noise=nan", "search.noise"),
        ("search.noise=inf", "search.noise"),
        ("search.noise=0", "search.noise"),
        ("search.noise=-1", "search.noise"),
        ("search.elites=0", "search.elites"),
        ("search.temperature=0", "search.temperature"),
        ("search.select=robustly", "search.select"),
        ("search.seed=-1", "search.seed"),
        ("search.robust_runs=0", "search.robust_runs"),
        ("search.robust_noise=0", "search.robust_noise"),
        ("search.robust_noise=nan", "search.robust_noise"),
        ("search.restarts=-1", "search.restarts"),
        ("search.restarts=101", "search.restarts"),
        # a restart is decided by the polished plans' goal: none to polish, no goal: refused
        ("search.restarts=1 search.polish=0", "search.restarts"),
        ("search.restarts=1 goal={}", "search.restarts"),
    ],
)
def test_bad_search_settings_are_refused_in_one_line(override, words):
    with pytest.raises(ConfigError) as e:
        load_task("cartpole-wall", override.split(" "))
    assert str(e.value).startswith(words) and "\n" not in str(e.value)


def test_search_settings_load_and_smoke_shrinks_them():
    cfg = load_task("cartpole-wall", ["search.method=mppi", "search.knots=12"])
    assert cfg.search.method == "mppi" and cfg.search.knots == 12
    assert load_task("cartpole-wall").search is None
    small = load_task("cartpole-wall", ["search.method=cem"], smoke=True).search
    assert small.samples < cfg.search.samples and small.knots <= 3
    from hydroilqr.problem.smoke import shrink_search

    for shrink, left in (({}, 1), ({"search.restarts": 3}, 3)):  # (a smoke: section's own wins)
        data = {"search": {"restarts": 3}}
        shrink_search(data, shrink)
        assert data["search"]["restarts"] == left
    data = {"search": {}}
    shrink_search(data, {})
    assert "restarts" not in data["search"]  # (none: the default 0)


# ---------------------------------------------------------------------------- plants


@pytest.fixture(scope="module")
def cartpole():
    from hydroilqr.model.task import Task

    return Task.load("cartpole-wall", ["num_steps=15", "search.space=position"])


def test_pd_rollout_is_playbacks_law(cartpole):
    """A position-space rollout applies, at every step, the PD+ law that playback executes
    (one function: model.pd.pd_torque), with gravity compensation as feed-forward, clipped
    to the effort limits."""
    from hydroilqr.control import playback
    from hydroilqr.model import pd

    assert playback.pd_torque is pd.pd_torque
    dyn = cartpole.dynamics
    qi, vi = pd.actuated_indices(dyn.plant)
    Q_ref = cartpole.x0[qi] + 0.2 * np.sin(np.linspace(0, 3, 16))[:, None]
    X, U = pd.pd_rollout(dyn, cartpole.x0, Q_ref, kp=50.0, kd=5.0)
    for k in range(15):
        x = X[k]
        v_ref = (Q_ref[k + 1] - Q_ref[k]) / dyn.dt
        tau = dyn.gravity_compensation(x) - 50.0 * (x[qi] - Q_ref[k]) - 5.0 * (x[vi] - v_ref)
        assert np.array_equal(U[k], dyn.clip_to_limits(tau))
        assert np.array_equal(X[k + 1], dyn.step(x, U[k]))
    assert np.max(np.abs(X[-1, qi] - Q_ref[-1])) < np.max(np.abs(X[0, qi] - Q_ref[-1]))


def test_a_search_space_decodes_and_costs_with_the_tasks_own_cost(cartpole):
    from hydroilqr.solver.search import SearchSpace, run_search

    space = SearchSpace(cartpole)
    theta = space.nominal(cartpole)
    assert theta.shape == (8, 1) and np.allclose(theta[0], cartpole.x0[space.qi])
    # the first knot is pinned at the start posture (equal bounds), the others are free
    assert np.array_equal(space.lower[0], cartpole.x0[space.qi])
    assert np.array_equal(space.upper[0], cartpole.x0[space.qi])
    assert np.all(space.upper[1:] > space.lower[1:])
    cmd = space.decode(theta)
    assert cmd.shape == (16, 1)
    r = space.rollout(cartpole, cmd)
    assert r.cost == pytest.approx(cartpole.cost.total(r.X, r.U))
    torque = SearchSpace(cartpole, SearchConfig(space="torque", knots=3, order=0))
    assert torque.decode(torque.nominal(cartpole)).shape == (15, 1)
    small = SearchConfig(space="torque", samples=6, iterations=2, knots=3, elites=2)
    space2, res = run_search(cartpole, settings=small)
    assert res.best.cost <= res.costs[0, 0] and res.costs.shape == (2, 6)


def test_the_same_best_sample_with_one_and_two_dask_workers(dask_scheduler):
    """Samples drawn centrally, evaluated in batches on workers that hold their plant: the
    same costs and best sample with 1 worker (a local cluster of its own) and 2 (the tests'
    shared cluster) for one seed."""
    from hydroilqr.studies.search import run_search

    ref = {
        "name": "cartpole-wall",
        "overrides": ["num_steps=10", "search.samples=6", "search.iterations=2", "search.knots=3"],
        "config": None,
        "smoke": False,
    }
    runs = [run_search(ref, workers=1), run_search(ref, scheduler=dask_scheduler)]
    assert [r.workers for r in runs] == [1, 2]
    assert np.array_equal(runs[0].result.costs, runs[1].result.costs)
    assert np.array_equal(runs[0].result.best.knots, runs[1].result.best.knots)
    assert np.array_equal(runs[0].solution.X, runs[1].solution.X)


def test_a_worker_evaluates_a_changed_task_file_as_it_now_reads(tmp_path, dask_scheduler):
    """A worker holds the plant of the task it last evaluated (``held``): a task file changed
    at the same path between two searches on one cluster (a long-lived ``--scheduler``) is
    evaluated as it now reads, with the same costs as the same text at another path."""
    import yaml

    from hydroilqr.studies.search import run_search

    path = tmp_path / "task.yaml"
    small = ["num_steps=10", "search.samples=4", "search.iterations=1", "search.knots=3"]
    ref = {"name": str(path), "overrides": small, "config": None, "smoke": False}
    path.write_text(yaml.safe_dump({"extends": "cartpole-wall"}))
    first = run_search(ref, scheduler=dask_scheduler).result.costs
    path.write_text(yaml.safe_dump({"extends": "cartpole-wall", "cost": {"R": 1.0}}))
    again = run_search(ref, scheduler=dask_scheduler).result.costs
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "task.yaml").write_text(path.read_text())
    fresh = run_search({**ref, "name": str(tmp_path / "b" / "task.yaml")}, scheduler=dask_scheduler)
    assert not np.array_equal(first, fresh.result.costs)  # (the change matters)
    assert np.array_equal(again, fresh.result.costs)


def test_select_by_goal_cost_or_transfer():
    from hydroilqr.studies.search import PolishResult, select

    class _Sol:
        def __init__(self, cost):
            self.final_cost = cost

    def r(i, cost, met, moved=None):
        out = PolishResult(index=i, solution=_Sol(cost), goal={"met": met})
        out.transfer = None if moved is None else {"goal_met": moved}
        return out

    rs = [r(0, 5.0, False, False), r(1, 9.0, True, False), r(2, 7.0, True, True)]
    assert select(rs, "goal") == 1  # the first that meets the goal, not the cheapest
    assert select(rs, "cost") == 0
    assert select(rs, "transfer") == 2  # the first whose playback meets it
    assert select([r(0, 5.0, False), r(1, 3.0, False)], "goal") == 1  # none met: cheapest
    assert select([r(0, math.inf, None)], "goal") is None


def test_select_robust_takes_the_plan_whose_perturbed_resolves_meet_the_goal():
    from hydroilqr.studies.search import PolishResult, select

    class _Sol:
        def __init__(self, cost):
            self.final_cost = cost

    def r(i, met, held=None):
        out = PolishResult(index=i, solution=_Sol(1.0 + i), goal={"met": met})
        out.robust = None if held is None else {"runs": 3, "met": held}
        return out

    rs = [r(0, False), r(1, True, 1), r(2, True, 3), r(3, True, 3)]
    assert select(rs, "robust") == 2  # the most re-solves meeting the goal, the first of equals
    assert select([r(0, True, 0), r(1, True, 0)], "robust") == 0  # none held: as goal
    assert select([r(0, False), r(1, False)], "robust") == 0  # none met: the cheapest


ROBUST = [
    "num_steps=10",
    "search.samples=4",
    "search.iterations=2",
    "search.knots=3",
    "search.polish=2",
    "search.select=robust",
    "search.robust_runs=2",
    "solver.max_iterations=20",
    # a goal the smoke problem's polished plans meet, so that their re-solves run
    "goal={final_angle_error_rad: {max: 10.0}}",
]


def test_select_robust_resolves_each_plan_that_meets_the_goal_on_dask(dask_scheduler):
    """``select: robust`` on a smoke problem: each polished plan that meets the goal is
    re-solved ``robust_runs`` times from its torques perturbed (the same perturbations the
    robustness command draws), and the chosen plan is one of those; in a robustness run's own
    process the same re-solves give the same counts."""
    from hydroilqr.studies.search import perturbed_starts, run_search, search_start

    ref = {"name": "cartpole-wall", "overrides": ROBUST, "config": None, "smoke": False}
    run = run_search(ref, scheduler=dask_scheduler, polish=True)
    met = [r for r in run.polished if r.goal.get("met") is True]
    assert met, "the smoke problem's goal should be met by a polished plan"
    for r in run.polished:
        assert (r.robust is not None) == (r.goal.get("met") is True)
        if r.robust is not None:
            assert r.robust["runs"] == 2 and len(r.robust["goal_met"]) == 2
            assert r.robust["met"] == sum(r.robust["goal_met"])
    assert run.chosen in [r.index for r in met]
    rec = run.record()["polish"]
    assert rec["select"] == "robust" and "robust" in rec["results"][run.chosen]
    task = load_task_obj(ref)
    U0 = run.space.rollout(task, run.result.candidates[0].command).U
    starts = perturbed_starts(task, run.space.settings, U0)
    assert len(starts) == 2 and not np.array_equal(starts[0], U0)
    assert np.allclose(starts[0], U0, rtol=1e-6, atol=1e-6)
    here = search_start({**ref, "overrides": [*ROBUST, "search.seed=0"]}, 1, 0)
    assert not here.error and here.goal.get("met") is True


def load_task_obj(ref):
    from hydroilqr.model.task import Task

    return Task.load(ref["name"], ref["overrides"], ref["config"], ref["smoke"])


def test_a_search_whose_workers_all_die_stops_with_its_best_so_far():
    """Every worker gone: ``gather_within`` gives up after its patience (a plain gather would
    wait forever), and the search ends with what it had."""
    from hydroilqr.studies.cluster import open_client
    from hydroilqr.studies.multistart import _close
    from hydroilqr.studies.search import WorkersLost, gather_within

    client, cluster = open_client(None, 1)
    try:
        assert gather_within(client, [client.submit(sum, [1, 2])], 5.0) == [3]
        cluster.scale(0)
        deadline = time.monotonic() + 60
        while client.nthreads() and time.monotonic() < deadline:
            time.sleep(0.2)
        fut = client.submit(sum, [3, 4], pure=False)
        t0 = time.monotonic()
        with pytest.raises(WorkersLost, match="every Dask worker was gone for 1 s"):
            gather_within(client, [fut], patience=1.0, poll=0.2)
        assert time.monotonic() - t0 < 30
    finally:
        _close(client, cluster)


def test_pusher_puck_searches_in_position_space_from_a_still_start():
    """The built-in whose search: section solve runs: out of contact at the start, its
    smoke-sized search (local evaluation) keeps the start posture as its first knot and
    never ends above its nominal's cost."""
    from hydroilqr.model.task import Task
    from hydroilqr.solver.search import run_search

    task = Task.load("pusher-puck", smoke=True)
    assert task.config.search.space == "position" and task.config.goal
    space, res = run_search(task)
    assert np.array_equal(res.best.knots[0], task.x0[space.qi])
    assert res.best.cost <= res.costs[0, 0] and np.isfinite(res.costs).all()


def test_a_robustness_run_with_search_searches_with_its_own_seed_and_polishes():
    """``robustness --search``: run k searches with the seed ``seed + k - 1`` (as ``solve
    --set search.seed=...`` would) and polishes its candidates; a task without a search:
    section is a failed run, not an exception."""
    from hydroilqr.model.task import Task
    from hydroilqr.solver.search import run_search
    from hydroilqr.studies.search import search_start

    name = "pusher-puck"
    one = ["search.polish=1", "search.polish_guess=false", "search.restarts=0"]
    ref = {"name": name, "overrides": one, "config": None, "smoke": True}
    r = search_start(ref, 2, 3)  # run 2 of seed 3: the search's seed 4
    assert not r.error and r.solution is not None and "met" in r.goal
    assert r.polish["chosen"] == 0 and r.polish["start"] == "sample"
    task = Task.load(name, [*one, "search.seed=4"], smoke=True)
    space, res = run_search(task)
    assert r.solution.costs[0] == pytest.approx(space.rollout(task, res.best.command).cost)
    bare = search_start({**ref, "name": "cartpole-wall", "overrides": []}, 1, 0)
    assert bare.solution is None and "no search: section" in bare.error


def test_robustness_search_refuses_a_task_without_a_search_section(tmp_path, capsys):
    from hydroilqr import cli

    rc = cli.main(["robustness", "cartpole-wall", "--search", "--out", str(tmp_path / "r")])
    assert rc == 2 and "--search: cartpole-wall has no search: section" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_the_tasks_guess_is_polished_last_as_ilqr_alone_solves_it():
    """``search.polish_guess`` (default on): the last polish start is the task's own guess,
    solved with its continuation stages as iLQR alone solves it, so that a search + polish
    never passes over the plan iLQR alone finds; in ``robustness --search`` run k's guess is
    iLQR alone's run k (the same perturbed guess, the same solve). Off: samples only."""
    from hydroilqr.model.task import Task
    from hydroilqr.solver.search import SearchSpace, run_search
    from hydroilqr.studies.multistart import solve_start
    from hydroilqr.studies.search import guess_start, polish_one, polish_starts, search_start

    name, over = "pusher-puck", ["search.polish=2", "search.restarts=0"]
    task = Task.load(name, over, smoke=True)
    assert task.config.search.polish_guess and task.config.continuation
    space, res = run_search(task)
    starts = polish_starts(task, space, res)
    assert [g for _, g in starts] == [False] * len(res.candidates) + [True]
    assert np.array_equal(starts[-1][0], task.initial_guess(task.config.steps))
    off = Task.load(name, [*over, "search.polish_guess=false"], smoke=True)
    off_space = SearchSpace(off)  # (the starts follow the space's settings)
    assert [g for _, g in polish_starts(off, off_space, res)] == [False] * len(res.candidates)

    ref = {"name": name, "overrides": over, "config": None, "smoke": True}
    alone = solve_start(ref, 3, 0, 1e-3)  # iLQR alone's run 3 (with the approach stage)
    guess = polish_one(ref, guess_start(task, 1e-3, 0, 3), 9, guess=True)
    assert guess.guess and guess.record()["start"] == "guess"
    assert "continuation" in guess.solution.extra  # the stages ran
    assert np.array_equal(guess.solution.U, alone.solution.U)
    sample = polish_one(ref, starts[0][0], 0)
    assert "continuation" not in (sample.solution.extra or {})  # a sample: the task as written

    r = search_start(ref, 3, 0, 1e-3)
    assert not r.error and len(r.polish["goal_met"]) == 3  # 2 samples, the guess
    assert r.polish["start"] == ("guess" if r.polish["chosen"] == len(res.candidates) else "sample")


def test_a_robustness_record_says_which_polished_start_was_chosen():
    from hydroilqr.studies.robustness import RunResult

    polish = {"chosen": 3, "start": "guess", "goal_met": [False, False, False, True]}
    assert RunResult(task="t", index=1, polish=polish).record()["polish"] == polish
    assert "polish" not in RunResult(task="t", index=1).record()  # iLQR alone: none


# ---------------------------------------------------------------------------- restarts

#: A smoke problem whose goal no plan meets (every restart runs) and one whose goal any meets.
NEVER = [
    "num_steps=10",
    "search.samples=4",
    "search.iterations=2",
    "search.knots=3",
    "search.polish=2",
    "search.polish_guess=false",
    "search.restarts=2",
    "solver.max_iterations=5",
    "goal={final_angle_error_rad: {max: 1.0e-12}}",
]
ALWAYS = [*NEVER[:-1], "goal={final_angle_error_rad: {max: 10.0}}"]


def test_a_restarts_seed_comes_from_the_seed_and_its_number():
    """Restart r's seed: the seed itself for r = 0, else drawn from (seed, r): the same for
    the same pair, distinct across restarts and from the seeds seed + i that robustness's
    other runs and a receding search's windows use."""
    from hydroilqr.solver.search import restart_seed

    assert restart_seed(7, 0) == 7
    seeds = [restart_seed(s, r) for s in range(20) for r in range(1, 4)]
    assert seeds == [restart_seed(s, r) for s in range(20) for r in range(1, 4)]
    assert len(set(seeds)) == len(seeds) and not set(seeds) & set(range(40))
    assert all(0 <= s < 2**31 for s in seeds)


def test_restarts_search_again_while_no_polished_plan_meets_the_goal(dask_scheduler):
    """``search.restarts``: no polished plan meets the goal, so the search runs again with each
    restart's seed and its best samples are polished too (numbered on, tagged with their
    restart), the same with 1 worker and 2 and in a robustness run's own process; a plan
    that meets the goal in the first round stops them."""
    from hydroilqr.model.task import Task
    from hydroilqr.solver.search import restart_seed
    from hydroilqr.solver.search import run_search as search_here
    from hydroilqr.studies.search import run_search, search_start

    ref = {"name": "cartpole-wall", "overrides": NEVER, "config": None, "smoke": False}
    runs = [run_search(ref, workers=1, polish=True),
            run_search(ref, scheduler=dask_scheduler, polish=True)]  # fmt: skip
    for run in runs:
        assert [(r.restart, r.seed) for r in run.restarts] == [(1, restart_seed(0, 1)),
                                                               (2, restart_seed(0, 2))]  # fmt: skip
        assert [r.index for r in run.polished] == list(range(6))
        assert [r.search for r in run.polished] == [0, 0, 1, 1, 2, 2]
        assert not run.met() and run.chosen is not None
        rec = run.record()
        assert [r["seed"] for r in rec["restarts"]] == [r.seed for r in run.restarts]
        assert [r.get("search", 0) for r in rec["polish"]["results"]] == [0, 0, 1, 1, 2, 2]
    one, two = runs
    for a, b in zip(one.restarts, two.restarts):
        assert np.array_equal(a.result.costs, b.result.costs)
    assert [r.cost for r in one.polished] == [r.cost for r in two.polished]
    assert one.chosen == two.chosen
    # restart 1's search is the search of its seed
    task = Task.load("cartpole-wall", [*NEVER, f"search.seed={restart_seed(0, 1)}"])
    _, alone = search_here(task)
    assert np.array_equal(alone.costs, one.restarts[0].result.costs)
    # a robustness run (seed 0, run 1: the search's seed 0) restarts alike in its own process
    here = search_start(ref, 1, 0)
    assert not here.error and here.polish["restarts"] == 2
    assert len(here.polish["goal_met"]) == 6 and here.solution.final_cost == pytest.approx(
        one.polished[one.chosen].cost
    )
    met = run_search({**ref, "overrides": ALWAYS}, scheduler=dask_scheduler, polish=True)
    assert met.met() and not met.restarts and len(met.polished) == 2
    assert search_start({**ref, "overrides": ALWAYS}, 1, 0).polish["restarts"] == 0
