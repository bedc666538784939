"""Test tiers: ``./hydroilqr test --fast`` (pytest --fast, tests/conftest.py) leaves out the
tests marked slow, the full-size solves; without it every test runs."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FILES = ["tests/integration/test_transfer.py", "tests/integration/test_mpc.py"]

# Loaded into the collecting pytest (-p): every collected test with its slow marker, before
# tests/conftest.py deselects any; then the ones --fast deselected and the ones it kept.
PROBE = """
import pytest

@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    for item in items:
        slow = item.get_closest_marker("slow") is not None
        print("EVERY", "slow" if slow else "other", item.nodeid)

def pytest_deselected(items):
    for item in items:
        print("DESELECTED", item.nodeid)

@pytest.hookimpl(trylast=True)
def pytest_collection_finish(session):
    for item in session.items:
        print("KEPT", item.nodeid)
"""


def test_fast_deselects_the_slow_tests_and_keeps_the_others(tmp_path):
    """One collection with --fast (a collection loads Drake: one process, not three)."""
    (tmp_path / "tier_probe.py").write_text(PROBE)
    cmd = [sys.executable, "-m", "pytest", *FILES, "--collect-only", "--fast", "-s"]
    cmd += ["-p", "no:cacheprovider", "-p", "tier_probe"]
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)
    lines = [line.split(" ", 1) for line in out.stdout.splitlines()]  # (ids may hold spaces)
    every = {w[1].split(" ", 1)[1] for w in lines if w[0] == "EVERY"}
    slow = {w[1].split(" ", 1)[1] for w in lines if w[0] == "EVERY" and w[1].startswith("slow ")}
    deselected = {w[1] for w in lines if w[0] == "DESELECTED"}
    kept = {w[1] for w in lines if w[0] == "KEPT"}
    assert slow and len(every - slow) > 10, out.stdout[-2000:]  # (both kinds are there)
    assert deselected == slow
    assert kept == every - slow
