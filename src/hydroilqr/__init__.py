"""hydroilqr: contact-implicit trajectory optimization with iLQR over Drake's hydroelastic
contact.

Data flow: task YAML (config.py) -> plant/dynamics (plant.py) -> derivatives (derivatives.py)
-> iLQR (ilqr.py, cost.py) -> Solution (solution.py) -> outputs, playback, replay.
"""

import locale as _locale
import sys as _sys

if not _sys.flags.utf8_mode and _locale.getpreferredencoding(False).lower() in (
    "ascii",
    "ansi_x3.4-1968",
):  # pydrake 1.51 reads a UTF-8 file with the locale's encoding and fails to import
    raise ImportError(
        "pydrake cannot start with an ASCII text encoding (e.g. LC_ALL=C with PYTHONUTF8=0): "
        "set PYTHONUTF8=1 or a UTF-8 locale (LC_ALL=C.UTF-8)"
    )

from hydroilqr.model.derivatives import DerivativeMethod, linearize  # noqa: E402
from hydroilqr.model.plant import Dynamics, SimulationError  # noqa: E402
from hydroilqr.output.progress import IterationTable  # noqa: E402
from hydroilqr.problem.config import ConfigError, SolverConfig, TaskConfig  # noqa: E402
from hydroilqr.problem.task import Task  # noqa: E402
from hydroilqr.solver.api import solve  # noqa: E402
from hydroilqr.solver.explain import explain  # noqa: E402
from hydroilqr.solver.ilqr import IterationInfo  # noqa: E402
from hydroilqr.solver.solution import Solution  # noqa: E402

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
    "explain",
    "linearize",
    "solve",
]
__version__ = "0.1.0"
