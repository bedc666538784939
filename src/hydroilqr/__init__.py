"""hydroilqr: contact-implicit trajectory optimization with iLQR over Drake's hydroelastic
contact.

Data flow: task YAML (config.py) -> plant/dynamics (plant.py) -> derivatives (derivatives.py)
-> iLQR (ilqr.py, cost.py) -> Solution (solution.py) -> outputs, playback, replay.
"""

import importlib as _importlib
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

# The public API, imported on first use (``import hydroilqr`` stays cheap: the command line
# can refuse bad input before Drake is loaded).
_API = {
    "ConfigError": "hydroilqr.problem.errors",
    "DerivativeMethod": "hydroilqr.model.derivatives",
    "Dynamics": "hydroilqr.model.plant",
    "IterationInfo": "hydroilqr.solver.ilqr",
    "IterationTable": "hydroilqr.output.progress",
    "SimulationError": "hydroilqr.model.plant",
    "Solution": "hydroilqr.solver.solution",
    "SolverConfig": "hydroilqr.problem.solver",
    "Task": "hydroilqr.model.task",
    "TaskConfig": "hydroilqr.problem.task",
    "explain": "hydroilqr.solver.explain",
    "linearize": "hydroilqr.model.derivatives",
    "solve": "hydroilqr.solver.api",
}


def __getattr__(name: str):
    if name in _API:
        value = getattr(_importlib.import_module(_API[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'hydroilqr' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_API])


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
