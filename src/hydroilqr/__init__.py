"""hydroilqr: contact-implicit trajectory optimization with iLQR over Drake's hydroelastic
contact.

Data flow: task YAML (config.py) -> plant/dynamics (plant.py) -> derivatives (derivatives.py)
-> iLQR (ilqr.py, cost.py) -> Solution (solution.py) -> outputs, playback, replay.
"""

from .api import solve
from .config import ConfigError, SolverConfig, TaskConfig
from .derivatives import DerivativeMethod, linearize
from .ilqr import IterationInfo
from .plant import Dynamics, SimulationError
from .progress import IterationTable
from .solution import Solution
from .task import Task

__all__ = [
    "ConfigError",
    "DerivativeMethod",
    "Dynamics",
    "IterationInfo",
    "IterationTable",
    "SimulationError",
    "Solution",
    "SolverConfig",
    "Task",
    "TaskConfig",
    "linearize",
    "solve",
]
__version__ = "0.1.0"
