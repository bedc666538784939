"""Model instance names: one model file loaded twice under distinct names."""

from pathlib import Path

import numpy as np
import pytest

import hydroilqr
from hydroilqr import ConfigError, Task
from hydroilqr.metrics import validate_task

CARTPOLE = Path(hydroilqr.__file__).parent / "models" / "cartpole_wall" / "cartpole.sdf"


def _two_cartpoles(tmp_path, names=("left", "right")) -> Path:
    models = "\n".join(f"  - file: {CARTPOLE}\n    name: {n}" for n in names)
    path = tmp_path / "two.yaml"
    path.write_text(
        f"description: two cart-poles from one file\nmodels:\n{models}\n"
        "plant: {time_step: 0.01}\nhorizon: 0.05\n"
        "cost: {Q: {left::pole_pin: 1.0}, R: 0.01}\n"
    )
    return path


def test_one_file_loads_twice_with_distinct_instance_names(tmp_path):
    task = Task.load(str(_two_cartpoles(tmp_path)))
    plant = task.dynamics.plant
    assert plant.HasModelInstanceNamed("left") and plant.HasModelInstanceNamed("right")
    blocks = list(task.dynamics.layout.primitives)
    assert "left::pole_pin" in blocks and "right::pole_pin" in blocks
    assert task.dynamics.nu == 2  # both carts' actuators
    X = task.dynamics.rollout(task.x0, np.zeros((5, 2)))
    assert np.all(np.isfinite(X))


def test_without_names_the_second_copy_is_refused_in_one_line(tmp_path):
    path = tmp_path / "dup.yaml"
    path.write_text(
        f"models:\n  - file: {CARTPOLE}\n  - file: {CARTPOLE}\n"
        "plant: {time_step: 0.01}\nhorizon: 0.05\ncost: {R: 0.01}\n"
    )
    with pytest.raises(ConfigError, match=r"models\[1\]\.file: could not parse"):
        validate_task(Task.load(str(path)))


def test_a_name_used_twice_is_refused(tmp_path):
    with pytest.raises(ConfigError, match=r"models\[1\]\.name: a model instance named 'left'"):
        Task.load(str(_two_cartpoles(tmp_path, ("left", "left")))).validate()
