"""Joint position limits in a model file (issue 36): Drake enforces them as constraints under
the convex contact approximations (sap, similar, lagged) and ignores them under tamsi, as
docs/task-format.md says."""

from __future__ import annotations

import numpy as np
import pytest

from hydroilqr import Task
from tests.conftest import needs_tamsi

URDF = """<?xml version="1.0"?>
<robot name="arm">
  <link name="base"/>
  <joint name="weld" type="fixed"><parent link="world"/><child link="base"/></joint>
  <link name="arm">
    <inertial><origin xyz="0.1 0 0"/><mass value="0.1"/>
      <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial>
  </link>
  <joint name="spin" type="revolute">
    <parent link="base"/><child link="arm"/><axis xyz="0 0 1"/>
    <limit effort="1.0" lower="-0.5" upper="0.5" velocity="10"/>
  </joint>
  <transmission type="SimpleTransmission" name="spin_tr">
    <actuator name="spin"/><joint name="spin"/><mechanicalReduction>1</mechanicalReduction>
  </transmission>
</robot>
"""


@pytest.mark.parametrize(
    "approximation", ["sap", "similar", "lagged", pytest.param("tamsi", marks=needs_tamsi)]
)
def test_model_position_limits_hold_under_the_convex_approximations(tmp_path, approximation):
    (tmp_path / "arm.urdf").write_text(URDF)
    data = {
        "models": [{"file": "arm.urdf"}],
        "num_steps": 50,
        "plant": {"contact_approximation": approximation},
    }
    task = Task.from_dict(data, base_dir=tmp_path)
    X = task.dynamics.rollout(task.x0, np.full((50, 1), 0.5))  # pushes past the upper limit
    if approximation == "tamsi":
        assert X[-1, 0] > 1.0  # ignored
    else:
        assert X[-1, 0] == pytest.approx(0.5, abs=1e-3)
