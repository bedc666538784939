"""Issue 27, bounded inputs and waits, one-line failures: devices and oversized files as any
input, YAML alias bombs, horizons too large for memory, silent schedulers, an empty --out,
Drake failures, corrupted checkpoints and sweep points."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from hydroilqr.metrics import validate_task
from hydroilqr.problem import inputs
from hydroilqr.problem.config import ConfigError, load_raw, yaml_value

SMOKE_RH = {
    "receding_horizon.window_steps": 6,
    "receding_horizon.shift_steps": 2,
    "receding_horizon.resolves": 2,
    "receding_horizon.max_iterations": 1,
    "solver.max_iterations": 1,
    "num_steps": 0,
}


def cli(*args: str, timeout: float = 60, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "hydroilqr", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, **(env or {})},
    )


def one_line_error(r: subprocess.CompletedProcess) -> str:
    assert r.returncode != 0
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("hydroilqr: "), r.stderr
    return lines[0]


# -- YAML alias expansion ---------------------------------------------------------------------

BILLION_LAUGHS = """\
metric_params:
  a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]
  b: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a]
  c: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b]
  d: &d [*c,*c,*c,*c,*c,*c,*c,*c,*c]
  e: &e [*d,*d,*d,*d,*d,*d,*d,*d,*d]
  f: &f [*e,*e,*e,*e,*e,*e,*e,*e,*e]
  g: &g [*f,*f,*f,*f,*f,*f,*f,*f,*f]
  h: &h [*g,*g,*g,*g,*g,*g,*g,*g,*g]
  i: &i [*h,*h,*h,*h,*h,*h,*h,*h,*h]
"""


# -- bounded waits ----------------------------------------------------------------------------


class _Listener:
    """A loopback TCP listener that accepts and then stays silent, or answers HTTP."""

    def __init__(self, http: bool = False):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(4)
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.http, self.stop, self.conns = http, False, []
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        deadline = time.monotonic() + 60
        while not self.stop and time.monotonic() < deadline:
            try:
                c, _ = self.sock.accept()
            except OSError:
                continue
            self.conns.append(c)
            if self.http:
                c.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")

    def close(self):
        self.stop = True
        self.thread.join(2)
        for c in self.conns:
            c.close()
        self.sock.close()


def _parser(func):
    import argparse

    p = argparse.ArgumentParser()
    p.add_argument("cmd")
    p.set_defaults(func=func)
    return p


# -- checkpoints and sweep points -------------------------------------------------------------


@pytest.fixture(scope="module")
def receding_run(tmp_path_factory):
    from hydroilqr.model.task import Task
    from hydroilqr.solver import api

    d = tmp_path_factory.mktemp("rh")
    task = Task.load("cartpole-wall", SMOKE_RH)
    api.solve(task, checkpoint_dir=d)
    return task, d


def _rewrite(ck: Path, **changes):
    with np.load(ck) as z:
        arrays = {k: z[k] for k in z.files}
    arrays.update(changes)
    np.savez(ck, **arrays)
    os.replace(str(ck) + ".npz", ck) if Path(str(ck) + ".npz").exists() else None


# -- bounded reads ----------------------------------------------------------------------------


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom"])
def test_devices_as_yaml_are_refused_at_once(device):
    t = time.perf_counter()
    with pytest.raises(ConfigError, match="a character device, not a regular file"):
        load_raw(Path(device))
    assert time.perf_counter() - t < 1.0


def test_fifo_directory_and_oversized_yaml(tmp_path):
    fifo = tmp_path / "pipe.yaml"
    os.mkfifo(fifo)
    t = time.perf_counter()
    with pytest.raises(ConfigError, match="a named pipe"):
        load_raw(fifo)  # never waits for a writer
    assert time.perf_counter() - t < 1.0
    with pytest.raises(ConfigError, match="a directory"):
        inputs.read_bounded(tmp_path, "task file", 100)
    big = tmp_path / "big.yaml"
    big.write_text("a: 1\n" + "#" * inputs.MAX_YAML_BYTES)
    with pytest.raises(ConfigError, match=r"big.yaml: 1.0 MiB, more than the 1.0 MiB"):
        load_raw(big)


def test_extends_device_and_foreign_file_content_never_quoted(tmp_path):
    task = tmp_path / "t.yaml"
    task.write_text("extends: /dev/zero\n")
    with pytest.raises(ConfigError, match="/dev/zero: a character device"):
        load_raw(task)
    secret = tmp_path / "shadow"
    secret.write_text("root:$6$SECRETHASH:20228:0:99999:7:::\nbin:*:20228:0:99999:7:::\n")
    task.write_text(f"extends: {secret}\n")
    with pytest.raises(ConfigError) as e:
        load_raw(task)
    assert "SECRETHASH" not in str(e.value) and "20228" not in str(e.value)
    assert "no task setting" in str(e.value)


@pytest.mark.parametrize(
    "args",
    [
        ["check", "/dev/zero"],
        ["check", "cartpole-wall", "--config", "/dev/zero"],
        ["check", "cartpole-wall", "--set", "initial_guess=/dev/zero"],
        ["check", "cartpole-wall", "--set", "initial_guess=/dev/urandom.npz"],
        ["solve", "--task-file", "/dev/urandom", "--smoke"],
    ],
)
def test_cli_devices_fail_with_one_line(args, tmp_path):
    if "/dev/urandom.npz" in args[-1]:
        link = tmp_path / "u.npz"
        link.symlink_to("/dev/urandom")
        args = [*args[:-1], f"initial_guess={link}"]
    t = time.perf_counter()
    r = cli(*args, timeout=30)
    line = one_line_error(r)
    assert "character device" in line or "not a regular file" in line, line
    assert time.perf_counter() - t < 20  # interpreter and Drake start-up included


def test_initial_guess_cap_and_npz_bomb(tmp_path):
    from hydroilqr.model.task import Task

    big = tmp_path / "U.csv"
    with open(big, "wb") as f:
        f.truncate(inputs.MAX_TABLE_BYTES + 1)  # sparse: no disk
    task = Task.load("cartpole-wall", {"initial_guess": str(big)}, smoke=True)
    with pytest.raises(ConfigError, match="U.csv: 16.0 MiB, more than"):
        task.initial_guess(task.steps)
    # a small compressed archive that declares a huge array
    bomb = tmp_path / "U.npz"
    np.savez_compressed(bomb, U=np.zeros((3_000_000, 1)))
    assert bomb.stat().st_size < 1_000_000
    task = Task.load("cartpole-wall", {"initial_guess": str(bomb)}, smoke=True)
    with pytest.raises(ConfigError, match="uncompressed, more than"):
        task.initial_guess(task.steps)
    assert inputs.table_cap(10, 1) == inputs.MAX_TABLE_BYTES


def test_billion_laughs_refused(tmp_path):
    f = tmp_path / "bomb.yaml"
    f.write_text("extends: cartpole-wall\n" + BILLION_LAUGHS)
    t = time.perf_counter()
    with pytest.raises(ConfigError, match="aliases expand to more than 100000 values"):
        load_raw(f)
    assert time.perf_counter() - t < 1.0


def test_recursive_alias_refused_and_small_aliases_fine(tmp_path):
    f = tmp_path / "rec.yaml"
    f.write_text("a: &a [1, *a]\n")
    with pytest.raises(ConfigError, match="an alias refers to a node that contains it"):
        load_raw(f)
    assert yaml_value("{a: &x [1, 2], b: *x}") == {"a": [1, 2], "b": [1, 2]}


def test_cli_alias_bomb_in_metric_params_refused_before_solving(tmp_path):
    f = tmp_path / "bomb.yaml"
    f.write_text("extends: cartpole-wall\n" + BILLION_LAUGHS)
    r = cli("solve", str(f), "--smoke", "--out", str(tmp_path / "run"), timeout=30)
    assert "aliases expand" in one_line_error(r)
    assert not (tmp_path / "run" / "summary.json").exists()


# -- memory of a horizon ----------------------------------------------------------------------


def test_memory_estimate_refuses_huge_window_and_horizon(monkeypatch):
    from hydroilqr.model.task import Task

    monkeypatch.setenv(inputs.MEMORY_LIMIT_ENV, str(2 << 30))
    task = Task.load("cartpole-wall", {**SMOKE_RH, "receding_horizon.window_steps": 990000})
    with pytest.raises(ConfigError, match=r"receding_horizon.window_steps: 990000 time steps"):
        validate_task(task)
    task = Task.load("cartpole-wall", {"num_steps": 990000})  # under the step cap
    with pytest.raises(ConfigError, match=r"horizon: 990000 time steps of nx=4, nu=1 need"):
        validate_task(task)
    from hydroilqr.solver import api

    with pytest.raises(ConfigError, match="need about"):
        api.solve(task)  # the Python API checks too
    validate_task(Task.load("cartpole-wall", smoke=True))  # small tasks pass
    assert inputs.horizon_bytes(100, 4, 1) < inputs.horizon_bytes(100, 37, 12)


def test_memory_limit_default_and_bad_env(monkeypatch):
    monkeypatch.delenv(inputs.MEMORY_LIMIT_ENV, raising=False)
    assert inputs.available_memory() > 0
    monkeypatch.setenv(inputs.MEMORY_LIMIT_ENV, "lots")
    with pytest.raises(ConfigError, match="expected a number of bytes"):
        inputs.available_memory()


def test_cli_huge_window_refused_with_one_line():
    r = cli(
        "check",
        "cheetah-trot-1.0",
        "--smoke",
        "--set",
        "receding_horizon.window_steps=990000",
        timeout=60,
        env={inputs.MEMORY_LIMIT_ENV: str(2 << 30)},
    )
    assert "of memory" in one_line_error(r)


@pytest.mark.parametrize("http", [False, True])
def test_scheduler_probe_is_bounded(http):
    from hydroilqr.studies.cluster import _probe_scheduler

    lis = _Listener(http)
    try:
        t = time.perf_counter()
        with pytest.raises(ConfigError, match=f"--scheduler tcp://127.0.0.1:{lis.port}: "):
            _probe_scheduler(f"tcp://127.0.0.1:{lis.port}", seconds=2)
        assert time.perf_counter() - t < 5
    finally:
        lis.close()


def test_client_deadline_names_the_address():
    from hydroilqr.studies.cluster import _client_within

    def stalls(address, timeout):
        time.sleep(30)

    t = time.perf_counter()
    with pytest.raises(ConfigError, match="tcp://127.0.0.1:9: not connected within 1 s"):
        _client_within(stalls, "tcp://127.0.0.1:9", seconds=1)
    assert time.perf_counter() - t < 5


def test_cli_sweep_silent_scheduler_fails_within_30s(tmp_path):
    lis = _Listener()
    try:
        t = time.perf_counter()
        r = cli(
            "sweep",
            "cartpole-wall",
            "--smoke",
            "--param",
            "solver.regularization_init",
            "--values",
            "1e-6",
            "--out",
            str(tmp_path / "sw"),
            "--scheduler",
            f"tcp://127.0.0.1:{lis.port}",
            timeout=45,
        )
        assert time.perf_counter() - t < 30
    finally:
        lis.close()
    assert f"tcp://127.0.0.1:{lis.port}" in one_line_error(r)


# -- --out '' and one-line failures ---------------------------------------------------------


def test_empty_out_refused(tmp_path):
    r = cli("solve", "cartpole-wall", "--smoke", "--out", "", timeout=30)
    assert "--out: an empty directory name" in one_line_error(r)
    from hydroilqr.output.report import output_dir

    with pytest.raises(ConfigError, match="empty directory name"):
        output_dir("", "cartpole-wall")


def test_drake_failure_and_systemexit_are_one_line(monkeypatch, capsys):
    from hydroilqr import cli as cli_mod

    def drake_fails(args):
        raise RuntimeError(
            "Failure at multibody/plant/multibody_plant.cc:1(): condition 'AllFinite(q_v)' "
            "failed.\nmore detail"
        )

    def exits(args):
        raise SystemExit("pydrake: something went wrong\nsecond line")

    for func, code, text in ((drake_fails, 3, "Drake failure: Failure at"), (exits, 1, "error")):
        monkeypatch.setattr(cli_mod, "build_parser", lambda f=func: _parser(f))
        assert cli_mod.main(["x"]) == code
        err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
        assert len(err) == 1 and err[0].startswith(f"hydroilqr: {text}"), err


def test_checkpoint_hash_and_finiteness(receding_run, tmp_path):
    import shutil

    from hydroilqr.solver import receding

    task, d = receding_run
    ck = d / receding.CHECKPOINT
    st = receding.load_checkpoint(task, d)  # intact: accepted
    with np.load(ck) as z:
        assert "sha256" in z.files
    # a NaN state, the hash kept: refused by the hash
    bad = tmp_path / "a"
    shutil.copytree(d, bad)
    X = st.X.copy()
    X[-1, 0] = np.nan
    _rewrite(bad / receding.CHECKPOINT, X=X)
    with pytest.raises(ConfigError, match=r"checkpoint.npz: its content does not match its hash"):
        receding.load_checkpoint(task, bad)
    # a NaN state in a checkpoint without a hash (as before hashes): refused as non-finite
    with np.load(bad / receding.CHECKPOINT) as z:
        arrays = {k: z[k] for k in z.files if k != "sha256"}
    np.savez(bad / "c.npz", **arrays)
    os.replace(bad / "c.npz", bad / receding.CHECKPOINT)
    with pytest.raises(ConfigError, match="its X holds NaN"):
        receding.load_checkpoint(task, bad)
    # an intact checkpoint without a hash is accepted (older runs)
    with np.load(ck) as z:
        arrays = {k: z[k] for k in z.files if k != "sha256"}
    np.savez(bad / "c.npz", **arrays)
    os.replace(bad / "c.npz", bad / receding.CHECKPOINT)
    receding.load_checkpoint(task, bad)


def test_cli_resume_from_nan_checkpoint_is_one_line(tmp_path):
    from hydroilqr.solver import receding

    sets = [f"--set={k}={v}" for k, v in SMOKE_RH.items() if k != "num_steps"]
    sets[-1:] = [sets[-1], "--set=solver.max_iterations=1"]
    # a checkpoint only: the run was interrupted after its first window
    from hydroilqr.model.task import Task
    from hydroilqr.solver import api

    task = Task.load("cartpole-wall", [s.split("=", 1)[1] for s in sets])
    api.solve(task, checkpoint_dir=tmp_path)
    ck = tmp_path / receding.CHECKPOINT
    with np.load(ck) as z:
        X = z["X"].copy()
    X[0, 1] = np.nan
    _rewrite(ck, X=X)
    r = cli("solve", "cartpole-wall", *sets, "--resume", str(tmp_path), timeout=60)
    line = one_line_error(r)
    assert str(ck) in line and "does not match its hash" in line, line


def test_sweep_point_hash_and_recompute(tmp_path):
    from hydroilqr.output.results import POINT_HASH
    from hydroilqr.output.results import write_sweep_point as save_point
    from hydroilqr.studies.sweep import point_intact

    row = {"id": "p1", "status": "ok", "final_cost": 1.5}
    save_point(tmp_path, {"row": row, "arrays": {"X": np.ones((3, 2)), "U": np.zeros((2, 1))}})
    assert point_intact(tmp_path, json.loads((tmp_path / "p1.json").read_text()))
    with np.load(tmp_path / "p1.npz") as z:
        arrays = {k: z[k] for k in z.files}
    assert POINT_HASH in arrays
    arrays["X"] = arrays["X"].copy()
    arrays["X"][0, 0] = np.nan
    np.savez(tmp_path / "p1.npz", **arrays)
    os.replace(tmp_path / "p1.npz.npz", tmp_path / "p1.npz") if (
        tmp_path / "p1.npz.npz"
    ).exists() else None
    assert not point_intact(tmp_path, row)
    (tmp_path / "p1.npz").write_bytes(b"garbage")
    assert not point_intact(tmp_path, row)
    (tmp_path / "p1.npz").unlink()
    assert not point_intact(tmp_path, row)  # an ok point without arrays
    assert point_intact(tmp_path, {"id": "p2", "status": "failed"})
    # the row is covered too: a hand-edited cost no longer matches
    save_point(tmp_path, {"row": row, "arrays": {"X": np.ones((3, 2))}})
    assert not point_intact(tmp_path, {**row, "final_cost": 0.1})


def test_probe_and_client_accept_a_real_scheduler():
    import asyncio

    from distributed import Client, Scheduler

    from hydroilqr.studies.cluster import _client_within, _probe_scheduler

    async def main():
        async with Scheduler(port=0, host="127.0.0.1", dashboard_address=":0") as s:

            def connect():
                _probe_scheduler(s.address, seconds=5)
                _client_within(Client, s.address, seconds=10).close()

            await asyncio.get_running_loop().run_in_executor(None, connect)

    asyncio.run(main())
