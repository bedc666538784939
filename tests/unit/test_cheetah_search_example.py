"""examples/cheetah-trot-search.yaml: its PD+ gains are ones the explicit law can step.

The search's position space applies u_k = kp (q̄ − q_k) − kd (v_k − v̄_k) + g(x_k), held over
the plant's 5 ms step. The law's damping is explicit: on a joint of effective inertia I (the
joint's inertia with every other coordinate free, 1 / (M⁻¹)_jj) it is stable only for
kd < 2 I / dt. The Mini Cheetah's knees (about 0.0019 kg·m²) bound kd near 0.74 N·m·s/rad;
above it a knee off the ground rings at the step's Nyquist frequency up to its effort limit,
every perturbed sample of a window shakes the body, and the search keeps the standing nominal.
"""

from __future__ import annotations

import numpy as np
import pytest

from hydroilqr.model.pd import actuated_indices
from hydroilqr.model.task import Task
from hydroilqr.solver import sampling
from hydroilqr.solver.search import SearchSpace

EXAMPLE = "examples/cheetah-trot-search.yaml"


@pytest.fixture(scope="module")
def task():
    return Task.load(EXAMPLE)


def effective_inertias(task) -> np.ndarray:
    """[nu]: 1 / (M⁻¹)_jj of each actuated joint at the task's initial state."""
    plant = task.dynamics.plant
    ctx = plant.CreateDefaultContext()
    plant.SetPositionsAndVelocities(ctx, task.x0)
    Minv = np.linalg.inv(plant.CalcMassMatrix(ctx))
    _, vi = actuated_indices(plant)
    j = np.asarray(vi) - plant.num_positions()
    return 1.0 / np.diag(Minv)[j]


def test_the_example_damping_is_inside_the_explicit_law_bound(task):
    cfg = task.config.search
    assert cfg.space == "position"
    bound = 2.0 * effective_inertias(task) / task.dynamics.dt
    assert cfg.kd < bound.min()


def saturated_fraction(task, kd: float, seeds=(0, 1, 2), steps: int = 30) -> float:
    """The fraction of (step, joint) torques at their effort limit over perturbed windows
    (noise 0.2 rad on the standing targets) rolled out with damping kd."""
    t = task.with_overrides([f"search.kd={kd}"])
    space = SearchSpace(t, t.config.search, 0, steps)
    nominal = space.nominal(t)
    limit = np.asarray(t.dynamics.effort_limits, float)
    out = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        eps = sampling.colored_noise(rng, 2.0, (1, nominal.shape[1], nominal.shape[0]))[0].T
        knots = np.clip(nominal + 0.2 * eps, space.lower, space.upper)
        r = space.rollout(t, space.decode(knots))
        out.append(np.abs(r.U) >= 0.99 * limit)
    return float(np.mean(out))


def test_perturbed_targets_stay_off_the_effort_limits_where_the_bound_is_broken_they_ring(task):
    """The example's gains track perturbed targets without saturating; the former kd = 1.0
    (above the knees' bound) drives the joints to their limits."""
    assert saturated_fraction(task, task.config.search.kd) < 0.05
    assert saturated_fraction(task, 1.0) > 0.2
