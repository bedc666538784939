"""Test tiers: ``./hydroilqr test --fast`` (pytest --fast, tests/conftest.py) leaves out the
tests marked slow, the full-size solves; without it every test runs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _collect(*args: str) -> str:
    cmd = [sys.executable, "-m", "pytest", "tests/integration/test_mpc.py", "--collect-only"]
    cmd += ["-p", "no:cacheprovider", "-p", "no:xdist", *args]  # (-q: the addopts)
    out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    return out.stdout


def test_fast_deselects_the_slow_tests_and_keeps_the_others():
    full, fast = _collect(), _collect("--fast")
    slow = "test_finger_spin_loop_keeps_touching_the_wheel"  # the built-in's whole loop
    assert slow in full and slow not in fast and "(1 deselected)" in fast
    others = [line for line in full.splitlines() if "::" in line and slow not in line]
    assert len(others) > 10 and all(line in fast.splitlines() for line in others)
