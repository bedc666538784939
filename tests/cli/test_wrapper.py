"""./hydroilqr and tools/find-python: which Python the wrapper takes, and the one line it
prints when there is none (issue 55)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TOOLS = ("bash", "cat", "sha256sum", "cut", "sed", "head", "sort", "dirname")


def _path_with(tmp_path: Path, pythons: dict[str, str]) -> str:
    """A PATH directory holding the shell tools the scripts use and the given pythons
    (name -> interpreter), nothing else."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for tool in TOOLS:
        (bin_dir / tool).symlink_to(shutil.which(tool))
    for name, target in pythons.items():
        (bin_dir / name).symlink_to(target)
    return str(bin_dir)


def _run(args: list[str], path: str, home: Path, **extra: str) -> subprocess.CompletedProcess:
    env = {"PATH": path, "HOME": str(home), **extra}
    return subprocess.run(args, env=env, capture_output=True, text=True, timeout=60)


def test_find_python_takes_the_supported_one_on_path(tmp_path):
    mine = f"{sys.version_info.major}.{sys.version_info.minor}"
    path = _path_with(tmp_path, {"python3": sys.executable, "python2.7": sys.executable})
    r = _run([str(ROOT / "tools" / "find-python")], path, tmp_path)
    version, exe = r.stdout.strip().split(" ", 1)
    assert r.returncode == 0 and version == mine and Path(exe).exists()
    # asked for another version only: this interpreter is not it
    other = "3.13" if mine != "3.13" else "3.12"
    assert _run([str(ROOT / "tools" / "find-python"), other], path, tmp_path).returncode == 1


def test_the_wrapper_without_a_supported_python_says_which_work_in_one_line(tmp_path):
    """In a checkout without .venv (a copy of the wrapper's files)."""
    repo = tmp_path / "repo"
    for name in ("hydroilqr", "tools/find-python", "pyproject.toml", "constraints.txt"):
        (repo / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, repo / name)
    path = _path_with(tmp_path, {})
    for extra in ({}, {"PYTHON": "3.10"}, {"PYTHON": str(tmp_path / "missing")}):
        r = _run([str(repo / "hydroilqr"), "tasks"], path, tmp_path, **extra)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and not r.stdout, r.stderr
        assert lines[0].startswith("hydroilqr: ") and "3.11, 3.12 or 3.13" in lines[0]
        assert "pyenv install 3.12" in lines[0]
