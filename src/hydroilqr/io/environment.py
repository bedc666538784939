"""The environment a result was computed in: code commit, package versions, CPU, BLAS kernels,
cores. Contact-rich solves are sensitive to last-bit differences, so every result records it."""

from __future__ import annotations

import ctypes
import functools
import glob
import importlib.metadata as md
import os
import platform
import subprocess
from datetime import UTC, datetime
from pathlib import Path

import numpy


def cores() -> int:
    """Cores this process may run on (its CPU affinity), not the host's."""
    try:
        return len(os.sched_getaffinity(0)) or 1
    except (AttributeError, OSError):
        return os.cpu_count() or 1


#: Written beside the package when it is built (setup.py): the commit it was built from.
BUILD_COMMIT_FILE = "_build_commit.txt"


@functools.cache
def code_version() -> str:
    """The checkout's commit (+ "-dirty" if the package sources are modified), for provenance:
    a resumed sweep may mix points computed by different code. An installed package (not in
    a git checkout): the commit recorded when it was built, "COMMIT (installed build)", or
    "installed package, commit unknown"."""
    return package_code(Path(__file__).parent.parent)


def package_code(package_dir: Path) -> str:
    """``code_version`` of the package in ``package_dir``."""
    commit = _checkout_commit(package_dir)
    if commit:
        return commit
    try:
        built = (package_dir / BUILD_COMMIT_FILE).read_text(encoding="utf-8")[:64].strip()
    except (OSError, UnicodeDecodeError):
        built = ""
    return f"{built} (installed build)" if built else "installed package, commit unknown"


def _checkout_commit(package_dir: Path) -> str:
    """The commit of the git checkout whose tracked sources ``package_dir`` is ("" when it is
    not one: e.g. an installed copy, even inside another repository's ignored .venv)."""

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", *args], cwd=package_dir, text=True, capture_output=True, timeout=10
        ).stdout.strip()

    try:
        if not git("ls-files", "--", "__init__.py"):
            return ""
        head = git("rev-parse", "--short", "HEAD")
        dirty = git("status", "--porcelain", "--", ".")
    except (OSError, subprocess.SubprocessError):
        return ""
    return head + ("-dirty" if head and dirty else "")


def environment(command: str | None = None) -> dict:
    """What produced a result: code commit, package versions, CPU. Contact-rich solves are
    sensitive to last-bit floating-point differences, so a number is only comparable with
    numbers from the same environment. ``command``: the command line that produced it (the
    CLI passes its own; None from Python)."""

    def version(pkg: str) -> str | None:
        try:
            return md.version(pkg)
        except md.PackageNotFoundError:
            return None

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(
                (ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), cpu
            )
    except OSError:
        pass
    # Vector instructions decide which BLAS kernels run (last bits of every matrix product).
    try:
        # (numpy's private module: imported where its absence can be caught)
        from numpy._core._multiarray_umath import __cpu_features__ as feats  # noqa: PLC0415
    except ImportError:  # another numpy layout: not recorded
        feats = {}
    simd = [k for k in ("AVX2", "FMA3", "AVX512F", "AVX512_SKX", "ASIMD") if feats.get(k)]
    return {
        # when the result was written (UTC): a page or a summary says how old it is
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "code": code_version(),
        "python": platform.python_version(),
        "drake": version("drake"),
        "numpy": version("numpy"),
        "scipy": version("scipy"),
        "cpu": cpu,
        "cpu_features": simd,
        "blas_core": blas_core(),
        "cores": cores(),
        # 1-minute load average when the result was written: timings mean little on a busy host
        "load_average": round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None,
        # the command line that produced the result (None from Python)
        "command": command,
    }


def blas_core() -> str | None:
    """The kernel set numpy's OpenBLAS picked for this CPU (e.g. SkylakeX, Zen, Haswell), or
    None where it cannot be asked. Two machines with the same core give the same last bits."""
    libs = glob.glob(os.path.join(os.path.dirname(numpy.__file__), os.pardir, "numpy.libs", "*"))
    for path in sorted(p for p in libs if "openblas" in os.path.basename(p)):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename"):
            f = getattr(lib, name, None)
            if f is not None:
                f.restype = ctypes.c_char_p
                return f().decode(errors="replace")
    return None
