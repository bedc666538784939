"""Fixtures and helpers shared by the unit, integration and cli tests."""

from __future__ import annotations

import copy
import signal
from pathlib import Path

import numpy as np
import pytest
import yaml

from hydroilqr import Task
from hydroilqr.problem.capabilities import drake_has_tamsi, no_tamsi_message

# A test of TAMSI (plant.contact_approximation=tamsi, bench's path (a)) runs where the Drake
# has it: the pinned ones do (1.51.1 on Python 3.11, 1.56.0 on 3.12/3.13), Drake 1.57+ not.
needs_tamsi = pytest.mark.skipif(not drake_has_tamsi(), reason=no_tamsi_message("this test"))


def pytest_configure(config):
    """pytest-xdist's worker processes ignore SIGINT (the controller handles Ctrl+C), and an
    ignored SIGINT is inherited by every command a test starts: a test of Ctrl+C would then
    test nohup. Tests run as a terminal's foreground job does, with Python's own handler."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_addoption(parser):
    parser.addoption(
        "--fast",
        action="store_true",
        help="leave out the tests marked slow (the full-size solves): ./hydroilqr test --fast",
    )


def pytest_collection_modifyitems(config, items):
    """Tests marked ``slow`` (full-size solves) run first, in their own order: on worker
    processes they then start on different workers at once, instead of one of them starting
    last and running alone at the end. With ``--fast`` they are deselected."""
    if config.getoption("--fast"):
        slow = [item for item in items if item.get_closest_marker("slow") is not None]
        if slow:
            config.hook.pytest_deselected(items=slow)
            items[:] = [item for item in items if item.get_closest_marker("slow") is None]
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)  # (a stable sort)


@pytest.fixture(scope="session")
def dask_scheduler():
    """The address of one local Dask cluster shared by the tests that need some cluster but
    not their own: they pass it as ``--scheduler`` / ``scheduler=``. It is started as the
    commands start theirs (``open_client(None, 2)``: two single-threaded worker processes with
    hydroilqr's worker set-up), once per test process (each pytest-xdist worker), instead of
    once per test: a worker process's start-up and its first Drake import then cost seconds
    once. The tests of the commands' own local cluster (its start-up, ``--workers``, Ctrl+C,
    losing workers) start their own."""
    from hydroilqr.studies.cluster import open_client
    from hydroilqr.studies.multistart import _close

    client, cluster = open_client(None, 2)
    try:
        yield cluster.scheduler_address
    finally:
        _close(client, cluster)


ACROBOT = "package://drake/examples/acrobot/Acrobot.urdf"

# A tiny acrobot task: twenty steps, solves in a moment (the run-directory and CLI tests).
ACROBOT_TASK = {
    "name": "runs-acrobot",
    "models": [{"file": ACROBOT}],
    "plant": {"time_step": 0.02},
    "num_steps": 20,
    "blocks": {"angles": ["shoulder", "elbow"]},
    "cost": {"Q": {"angles": 1.0}, "R": 0.01, "Qf": {"angles": 50.0}, "nominal": {"angles": 1.0}},
    "solver": {"max_iterations": 30},
}


# A five-step acrobot task of the validation tests, changed key by key with edit().
BASE = {
    "name": "val",
    "models": [{"file": ACROBOT}],
    "plant": {"time_step": 0.02},
    "num_steps": 5,
    "blocks": {"angles": ["shoulder", "elbow"]},
    "initial_state": {"angles": [0.1, 0.0]},
    "cost": {
        "Q": {"angles": 1.0},
        "R": 0.01,
        "Qf": {"angles": 10.0},
        "nominal": {"angles": [3.14, 0.0]},
    },
    "solver": {"max_iterations": 1},
}


def edit(**changes):
    """BASE with dotted-key changes ('cost.Q.angles': -1); value None deletes the key."""
    data = copy.deepcopy(BASE)
    for dotted, value in changes.items():
        *path, last = dotted.split("__")
        node = data
        for p in path:
            node = node.setdefault(p, {})
        if value is None:
            node.pop(last, None)
        else:
            node[last] = value
    return data


def write_case(tmp_path: Path, spec) -> Path:
    path = tmp_path / "task.yaml"
    path.write_text(spec if isinstance(spec, str) else yaml.safe_dump(spec))
    return path


def assert_one_line(rc: int, out: str, err: str, needle: str) -> None:
    assert rc != 0
    assert "Traceback" not in err and "Traceback" not in out
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("hydroilqr: error: "), lines[0]
    assert needle in lines[0], lines[0]
    assert out.strip() == "", f"the solve started: {out}"


def write_task(tmp_path, base: dict | None = None, **changes):
    """Write the tiny acrobot task (or `base`), with top-level `changes`, to tmp_path/task.yaml."""
    path = tmp_path / "task.yaml"
    path.write_text(yaml.safe_dump({**(ACROBOT_TASK if base is None else base), **changes}))
    return path


@pytest.fixture(scope="module")
def cartpole():
    """The cart-pole-against-a-wall task at its full size."""
    return Task.load("cartpole-wall")


@pytest.fixture(scope="module")
def cartpole_rollout():
    """A 30-step cart-pole task with a random-input rollout: (task, X, U)."""
    task = Task.load("cartpole-wall", overrides=["num_steps=30"])
    rng = np.random.default_rng(0)
    U = 5.0 * rng.standard_normal((30, 1))
    X = task.dynamics.rollout(task.x0, U)
    return task, X, U


def rollout_plan(task, U, cost: float | None = None):
    """A plan that is just the rollout of U: [N, nu] from the task's x0 (no solve), as a
    Solution with zero gains; its cost is the task's unless ``cost`` is given."""
    from hydroilqr.solver.solution import PHASES, Solution

    dyn = task.dynamics
    N = U.shape[0]
    X = dyn.rollout(task.x0, U)
    J = task.cost.total(X, U) if cost is None else cost
    return Solution(
        X, U, np.zeros((N, dyn.nu, dyn.nx)), np.zeros((N, dyn.nu)), dyn.dt * np.arange(N + 1),
        np.array([J]), [], {p: [] for p in PHASES}, False, "max_iterations", "autodiff",
    )  # fmt: skip
