"""mpc.lockstep_latency: a lock-step loop that feels a fixed controller latency, as a real-time
run does, so that what real time would do can be checked without depending on the machine;
and the process time each update took (mpc.json's solve_cpu_seconds)."""

import dataclasses
import time
import types

import numpy as np
import pytest

from hydroilqr import Task
from hydroilqr.control import mpc
from hydroilqr.control.mpc import Controller, check_settings, run_mpc
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.mpc import MPCConfig

KW = dict(duration=0.3, rate=50.0, horizon=0.2)  # cartpole-wall: 10 ms steps, 2 per period


def _fake_clock(monkeypatch, seconds_per_call: float) -> None:
    """The loop's wall clock advances ``seconds_per_call`` at each reading: every update
    then takes that long, whatever the machine (the controller's own clock is untouched)."""
    now = [0.0]

    def perf_counter():
        now[0] += seconds_per_call
        return now[0]

    fake = types.SimpleNamespace(perf_counter=perf_counter, process_time=time.process_time)
    monkeypatch.setattr(mpc, "time", fake)


@pytest.mark.parametrize("delay_compensation", [False, True])
def test_a_realtime_run_whose_updates_fit_the_latency_runs_as_the_lockstep_one(
    monkeypatch, delay_compensation
):
    task = Task.load("cartpole-wall")
    kw = dict(KW, delay_compensation=delay_compensation)
    plain = run_mpc(task, MPCConfig(**kw))
    late = run_mpc(task, MPCConfig(lockstep_latency=0.01, **kw))
    assert not np.array_equal(late.X, plain.X)  # the latency is felt
    _fake_clock(monkeypatch, 0.004)  # each real-time update: 4 ms, within one 10 ms step
    rt = run_mpc(task, MPCConfig(realtime=True, **kw))
    np.testing.assert_array_equal(rt.X, late.X)
    np.testing.assert_array_equal(rt.U, late.U)
    assert late.stats()["lockstep_latency_s"] == 0.01


def test_latency_rounds_up_to_whole_steps_and_the_old_plan_runs_meanwhile(monkeypatch):
    plans = []
    real = Controller.update

    def spy(self, x, t, *a, **k):
        out = real(self, x, t, *a, **k)
        plans.append((t, out[0]))
        return out

    monkeypatch.setattr(Controller, "update", spy)
    task = Task.load("cartpole-wall", ["initial_state.pole_angular_velocity=0"])
    settings = MPCConfig(lockstep_latency=0.012, truth_overrides=["plant.gravity=[0,0,-12]"], **KW)
    res = run_mpc(task, settings)
    dt = task.dynamics.dt
    (_, first), (t1, second) = plans[0], plans[1]  # the first plan, the update at 0.02 s
    k = int(round(t1 / dt))
    for j in (k, k + 1):  # 12 ms: two steps of the first plan after the update began
        dx = res.X[j] - first.X[j]
        np.testing.assert_allclose(res.U[j], first.U[j] - first.K[j] @ dx)
    dx = res.X[k + 2] - second.X[2]  # then the update's plan, indexed from its measurement
    np.testing.assert_allclose(res.U[k + 2], second.U[2] - second.K[2] @ dx)


def test_update_cpu_seconds_are_recorded_per_update():
    task = Task.load("cartpole-wall")
    res = run_mpc(task, MPCConfig(**KW))
    cpu = res.stats()["solve_cpu_seconds"]
    assert len(res.cpu_seconds) == len(res.solve_seconds) > 0
    assert all(c >= 0 for c in res.cpu_seconds) and sum(res.cpu_seconds) > 0
    assert cpu["max"] >= cpu["p95"] >= cpu["p50"] >= 0


@pytest.mark.parametrize(
    "latency,extra,needle",
    [
        (-0.01, {}, "from 0 to below the duration"),
        (float("nan"), {}, "from 0 to below the duration"),
        (0.3, {}, "from 0 to below the duration"),
        (0.01, {"realtime": True}, "lock-step only"),
    ],
)
def test_latency_that_cannot_apply_is_refused(latency, extra, needle):
    task = Task.load("cartpole-wall")
    settings = dataclasses.replace(MPCConfig(**KW, **extra), lockstep_latency=latency)
    with pytest.raises(ConfigError, match=needle):
        check_settings(settings, task)
