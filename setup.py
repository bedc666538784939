"""Records the git commit a package is built from (``hydroilqr/_build_commit.txt``), so an
installed copy (``pip install .``), which has no checkout to ask, still names its code in
``--version`` and ``environment.code``. Everything else is in pyproject.toml."""

import subprocess
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py


def _git(*args: str) -> str:
    try:
        return subprocess.run(
            ["git", *args], cwd=Path(__file__).parent, text=True, capture_output=True, timeout=10
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


class BuildPyWithCommit(build_py):
    """build_py, plus the commit (``-dirty`` with changed sources) beside the package."""

    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            return  # an editable install runs from the checkout, which git reads directly
        head = _git("rev-parse", "--short", "HEAD")
        dirty = head and _git("status", "--porcelain", "--", "src")
        target = Path(self.build_lib) / "hydroilqr" / "_build_commit.txt"
        target.write_text(head + ("-dirty" if dirty else "") + "\n" if head else "")


setup(cmdclass={"build_py": BuildPyWithCommit})
