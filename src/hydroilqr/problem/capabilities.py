"""What the installed Drake can do, read without loading it (the command line checks its input
before Drake loads).

Drake 1.57 removed the TAMSI contact solver (``plant.contact_approximation=tamsi``, the paper's);
hydroilqr pins a Drake that has it on every supported Python (pyproject.toml), but a user may
install another. The capability is read from the type stubs pydrake ships with its bindings
(``pydrake/multibody/plant.pyi`` declares ``DiscreteContactApproximation.kTamsi`` where the
binding exists), not from a version number.
"""

from __future__ import annotations

import functools
import importlib.metadata
import importlib.util
from pathlib import Path

# Which Drakes have TAMSI: said in messages only (the check itself reads the bindings' stubs).
TAMSI_DRAKES = "Drake 1.56 and older have it (1.57 removed it)"


@functools.cache
def drake_has_tamsi() -> bool:
    """Whether the installed Drake binds the TAMSI contact solver. True when pydrake's stubs
    cannot be read (Drake itself then accepts or refuses ``tamsi`` when the plant is built)."""
    spec = importlib.util.find_spec("pydrake")
    if spec is None or not spec.submodule_search_locations:
        return True
    stub = Path(next(iter(spec.submodule_search_locations))) / "multibody" / "plant.pyi"
    try:
        return "kTamsi" in stub.read_text(encoding="utf-8")
    except OSError:
        return True


def drake_version() -> str:
    """The installed Drake's version, for messages ("unknown" when it is not installed)."""
    try:
        return importlib.metadata.version("drake")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def no_tamsi_message(what: str) -> str:
    """One line: ``what`` needs TAMSI, which this Drake lacks, and which Drakes have it."""
    return (
        f"{what} needs Drake's TAMSI contact solver, which this Drake ({drake_version()}) does "
        f"not have; {TAMSI_DRAKES}, and hydroilqr pins 1.51.1 on Python 3.11, 1.56.0 on 3.12 "
        "and 3.13"
    )
