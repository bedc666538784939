"""Issue 53, 18: in MPC, `cost.nominal_relative_to_start` is anchored once, to the task's
initial state; the controller does not re-base it on the measured state at each update."""

from __future__ import annotations

import numpy as np

from hydroilqr import Task
from hydroilqr.control.mpc import prepare


def test_a_relative_target_is_the_tasks_start_plus_the_offset_at_every_update():
    task = Task.load(
        "cartpole-wall",
        [
            "cost.nominal_relative_to_start=[cart_position]",
            "cost.nominal.cart_position=0.3",
            "initial_state.cart_position=0.1",
        ],
        smoke=True,
    )
    loop = prepare(task)
    cart = list(task.dynamics.layout.block("cart_position").coords)
    assert np.allclose(loop.ctrl.cost.x_nom[cart], 0.4)  # 0.1 at the start + 0.3
    for measured in (-0.2, 0.35):
        x = task.x0.copy()
        x[cart] = measured
        loop.ctrl.update(x, 0.0, 1, full=True)
        assert np.allclose(loop.ctrl.cost.x_nom[cart], 0.4)  # not measured + 0.3
