"""Test tiers: ``./hydroilqr test --fast`` (pytest --fast, tests/conftest.py) leaves out the
tests marked slow, the full-size solves; without it every test runs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FILES = ["tests/integration/test_transfer.py", "tests/integration/test_mpc.py"]


def _collected(*args: str) -> set[str]:
    """The test ids pytest collects from FILES with ``args`` (-q: the addopts)."""
    cmd = [sys.executable, "-m", "pytest", *FILES, "--collect-only", "-p", "no:cacheprovider"]
    out = subprocess.run([*cmd, *args], cwd=ROOT, capture_output=True, text=True, timeout=300)
    return {line for line in out.stdout.splitlines() if "::" in line}


def test_fast_deselects_the_slow_tests_and_keeps_the_others():
    every, slow, fast = _collected(), _collected("-m", "slow"), _collected("--fast")
    assert slow and len(every - slow) > 10  # (both kinds are there)
    assert fast == every - slow
