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
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.files import load_raw, yaml_value

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
    from hydroilqr.output.results import checkpointer
    from hydroilqr.solver import api

    d = tmp_path_factory.mktemp("rh")
    task = Task.load("cartpole-wall", SMOKE_RH)
    api.solve(task, checkpoint_dir=d, on_checkpoint=checkpointer(d))
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


def test_cli_sweep_silent_scheduler_is_one_line(tmp_path):
    """A scheduler that accepts the connection and never answers: one line naming it and
    the deadline given (--connect-timeout). The deadline itself is asserted by the two tests
    above (a wall-clock bound on a whole CLI run fails on a loaded machine without telling
    anything about the product)."""
    lis = _Listener()
    try:
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
            "--connect-timeout",
            "2",
            timeout=600,
        )
    finally:
        lis.close()
    line = one_line_error(r)
    assert f"tcp://127.0.0.1:{lis.port}" in line and "within 2 s" in line


@pytest.mark.parametrize("command", ["sweep", "search", "solve", "robustness"])
def test_connect_timeout_is_checked_before_work(command, capsys):
    """--connect-timeout goes with --scheduler, is a number of seconds above 0, and its
    default in the help is the cluster's."""
    from hydroilqr.cli import main
    from hydroilqr.cli.common import CONNECT_DEFAULT
    from hydroilqr.studies.cluster import CONNECT_SECONDS

    assert CONNECT_DEFAULT == CONNECT_SECONDS
    args = [command, "cartpole-wall", "--out", "/nonexistent/never"]
    if command == "sweep":
        args += ["--param", "cost.R", "--values", "1,2"]
    if command == "solve":
        args += ["--starts", "2"]
    for extra, message in [
        (["--connect-timeout", "2"], "--connect-timeout goes with --scheduler"),
        (["--scheduler", "tcp://127.0.0.1:9", "--connect-timeout", "0"], "above 0"),
        (["--scheduler", "tcp://127.0.0.1:9", "--connect-timeout", "nan"], "above 0"),
    ]:
        assert main([*args, *extra]) == 2, (command, extra)
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err


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
    from hydroilqr.output.results import checkpointer
    from hydroilqr.solver import api

    task = Task.load("cartpole-wall", [s.split("=", 1)[1] for s in sets])
    api.solve(task, checkpoint_dir=tmp_path, on_checkpoint=checkpointer(tmp_path))
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


# -- issue 53: model files, interrupts while loading, mpc timing, results' --out, commits ---

MODELS = Path(__file__).resolve().parents[2] / "src/hydroilqr/models"
CARTPOLE_SDF = MODELS / "cartpole_wall" / "cartpole.sdf"


def _cartpole_with(tmp_path: Path, extra: str, where: str = "link") -> Path:
    """A task of cartpole-wall whose model is the project's cartpole.sdf (``drake:`` tags, no
    namespace declared) with ``extra`` added inside its pole link (or its model)."""
    text = CARTPOLE_SDF.read_text()
    anchor = '<visual name="rod_visual">' if where == "link" else "</model>"
    (tmp_path / "model.sdf").write_text(text.replace(anchor, extra + anchor, 1))
    task = tmp_path / "task.yaml"
    task.write_text("extends: cartpole-wall\nmodels:\n  - file: model.sdf\n")
    return task


def _check_within(path: Path, seconds: int = 60) -> int:
    """``hydroilqr check`` in this process, failing (not hanging) if it waits on a file."""
    import signal

    from hydroilqr import cli as cli_mod

    def hung(*_):
        raise TimeoutError("the model check waited on a file")

    old = signal.signal(signal.SIGALRM, hung)
    signal.alarm(seconds)
    try:
        return cli_mod.main(["check", str(path)])
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


MESH = "<{kind} name='m'><geometry><mesh><uri>{uri}</uri></mesh></geometry></{kind}>"


@pytest.mark.parametrize(
    "case, extra, where, needle",
    [
        ("fifo-collision", MESH.format(kind="collision", uri="pipe.obj"), "link", "a named pipe"),
        ("zero-visual", MESH.format(kind="visual", uri="/dev/zero"), "link", "a character device"),
        ("fifo-include", "<include><uri>pipe.obj</uri></include>", "model", "a named pipe"),
        ("missing-include", "<include><uri>gone.sdf</uri></include>", "model", "does not exist"),
        ("huge-mesh", MESH.format(kind="visual", uri="big.obj"), "link", "more than the 256"),
    ],
)
def test_sdf_with_undeclared_drake_prefix_names_only_regular_bounded_files(
    tmp_path, capsys, case, extra, where, needle
):
    """Issue 53, 1-3: the project's own SDFs use ``drake:`` tags without declaring the
    namespace; the mesh and include guard read them all the same (it gave up on the XML
    error: a FIFO mesh hung check, /dev/zero grew to GBs, a FIFO include was dropped)."""
    os.mkfifo(tmp_path / "pipe.obj")
    with open(tmp_path / "big.obj", "wb") as f:
        f.truncate(inputs.MAX_MESH_BYTES + 1)  # (sparse)
    rc = _check_within(_cartpole_with(tmp_path, extra, where))
    cap = capsys.readouterr()
    assert rc == 2 and "Traceback" not in cap.err
    line = one_line_error(subprocess.CompletedProcess([], rc, cap.out, cap.err))
    assert "models[0].file: model.sdf names" in line and needle in line


def test_model_references_are_read_leniently_and_in_linear_time():
    """No reference is missed for an undeclared prefix, a '--' in a comment (Drake's parser
    takes both), and malformed text never raises."""
    refs = inputs.model_file_references
    for sdf in MODELS.glob("*/*.sdf"):
        assert refs(sdf.read_text()) == []  # (primitives only)
    sdf = (
        "<!-- a -- comment --><sdf><model name='m'><drake:x/><link name='l'><visual>"
        "<geometry><mesh><uri> a.obj </uri><drake:declare_convex/></mesh></geometry></visual>"
        "</link><include><uri><![CDATA[b.sdf]]></uri></include></model></sdf>"
    )
    assert refs(sdf) == [("a.obj", False), ("b.sdf", True)]
    urdf = '<robot><link name="l"><visual><geometry><mesh filename="c.stl"/></geometry>'
    assert refs(urdf + "</visual></link></robot>") == [("c.stl", False)]
    mjcf = '<mujoco><compiler meshdir="meshes"/><asset><mesh file="d.obj"/></asset></mujoco>'
    assert refs(mjcf + '<include file="e.xml"/>') == [("meshes/d.obj", False), ("e.xml", True)]
    assert refs("<a" * 200_000) == [] and refs("<mesh filename='x'") == []


def test_a_drake_package_that_cannot_be_downloaded_says_how_to_use_a_local_copy(tmp_path, capsys):
    """Issue 53, 19: drake_models is downloaded on first use; offline that fails, in one
    line naming package_map, which replaces Drake's own entry with a local directory."""
    from hydroilqr.model.plant import _refuse_failed_download

    message = (
        "PackageMap: when downloading 'drake_models', the downloader experienced an error: "
        "All downloads failed:\n\nCandidate https://example.org/models.tar.gz failed:\n<x>"
    )
    with pytest.raises(ConfigError) as e:
        _refuse_failed_download(message, "models[0].file", "package://drake_models/a.sdf")
    assert "package_map: {drake_models: DIRECTORY}" in str(e.value) and "\n" not in str(e.value)
    assert "unpack https://example.org/models.tar.gz" in str(e.value)
    local = tmp_path / "models" / "cartpole"
    local.mkdir(parents=True)
    (local / "cartpole.sdf").write_text(CARTPOLE_SDF.read_text())
    task = tmp_path / "task.yaml"
    task.write_text(
        "extends: cartpole-wall\npackage_map: {drake_models: models}\n"
        "models:\n  - file: package://drake_models/cartpole/cartpole.sdf\n"
    )
    assert _check_within(task) == 0, capsys.readouterr().err


def test_an_import_error_a_ctrl_c_caused_is_an_interruption(capsys):
    """Issue 53, 6: Ctrl+C while pydrake loads made it fail as ImportError."""
    from hydroilqr import cli as cli_mod

    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as k:
            raise ImportError("initialization failed") from k
    except ImportError as e:
        assert cli_mod._exit_code(e) == 130
    assert capsys.readouterr().err.strip() == "hydroilqr: interrupted"
    with cli_mod._interrupts_held() as held:
        os.kill(os.getpid(), __import__("signal").SIGINT)  # held, not raised
        time.sleep(0.05)
    assert held


def test_ctrl_c_while_pydrake_loads_is_raised_once_it_is_loaded():
    """Cut short, pydrake prints a 50-line stack from C++ and fails to import; loaded with
    the interrupt held, the KeyboardInterrupt comes after and pydrake works."""
    code = (
        "import os, signal, sys, threading\n"
        "from hydroilqr import cli\n"
        "sys.meta_path.insert(0, cli._DrakeLoadsWhole())\n"
        "threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGINT)).start()\n"
        "try:\n"
        "    import pydrake\n"
        "    print('not interrupted')\n"
        "except KeyboardInterrupt:\n"
        "    from pydrake.common import RandomGenerator\n"
        "    RandomGenerator()\n"
        "    print('interrupted after loading')\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert r.stdout.strip() in ("interrupted after loading", "not interrupted")


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--rate", "0.5", "--duration", "1"], "not shorter than the duration (1 s): no update"),
        (["--rate", "1e-300", "--duration", "1"], "no update would run"),
        (["--rate", "1", "--duration", "1"], "no update would run"),  # (only the first plan)
        (["--push", "0.05:cart:1,0,0", "--push-duration", "1e-9"], "shorter than one step"),
        (["--plant-time-step", "1e-9"], "--plant-time-step (mpc.plant_time_step) 1e-09 s"),
    ],
)
def test_mpc_timing_that_cannot_run_as_asked_is_refused_before_any_work(
    tmp_path, capsys, args, needle
):
    """Issue 53, 9, 10, 12: no update in the run (it ran, then failed on its summary), a
    push shorter than the step that applies it (recorded as 1e-9 s, applied for 10 ms), a
    plant step too fine (refused naming `horizon`)."""
    from hydroilqr import cli as cli_mod

    out = tmp_path / "m"
    rc = cli_mod.main(["mpc", "cartpole-wall", "--smoke", *args, "--out", str(out)])
    cap = capsys.readouterr()
    line = one_line_error(subprocess.CompletedProcess([], rc, cap.out, cap.err))
    assert rc == 2 and needle in line and not out.exists()


def test_results_proves_its_out_before_solving(tmp_path, monkeypatch, capsys):
    """Issue 53, 11: an unwritable docs/ failed after every task was solved."""
    from hydroilqr import cli as cli_mod
    from hydroilqr.studies import results

    def never(*_a, **_k):
        raise AssertionError("solved before --out was checked")

    monkeypatch.setattr(results, "solve_tasks", never)
    (tmp_path / "file").write_text("")
    assert cli_mod.main(["results", "cartpole-wall", "--out", str(tmp_path / "file")]) == 2
    assert "exists and is not a directory" in capsys.readouterr().err
    ro = tmp_path / "ro"
    ro.mkdir()
    if subprocess.run(["chattr", "+i", str(ro)], capture_output=True).returncode != 0:
        ro.chmod(0o555)  # (root writes into it: then the refusal is not testable)
        if os.geteuid() == 0:
            return
    try:
        assert cli_mod.main(["results", "cartpole-wall", "--out", str(ro)]) == 2
    finally:
        subprocess.run(["chattr", "-i", str(ro)], capture_output=True)
        ro.chmod(0o755)
    assert f"--out {ro}: not writable" in capsys.readouterr().err


@pytest.mark.parametrize("step", ["retire:0", "install:0"])
def test_a_commit_cut_short_is_visible_in_the_directory(tmp_path, step):
    """Issue 53, 13: killed while installing, the directory held only hidden entries; a
    visible file says what happened and what finishes it, and goes when it is finished."""
    from hydroilqr.io import rundir

    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text("old")
    script = (
        "from pathlib import Path\nfrom hydroilqr.io import rundir\n"
        f"with rundir.result_set(Path({str(out)!r}), ['summary.json']) as st:\n"
        "    (st / 'summary.json').write_text('new')\n"
    )
    env = {**os.environ, rundir.KILL_ENV: step}
    assert subprocess.run([sys.executable, "-c", script], env=env).returncode == -9
    visible = [p.name for p in out.iterdir() if not p.name.startswith(".")]
    assert rundir.MARKER in visible
    assert "hydroilqr" in (out / rundir.MARKER).read_text()
    assert rundir.solution_file(out) == out / "solution.npz"  # a reader completes it
    assert sorted(p.name for p in out.iterdir()) == ["summary.json"]
    assert (out / "summary.json").read_text() == "new"


def test_dask_workers_start_with_ctrl_c_blocked_and_this_process_keeps_it():
    """Issue 53, 7: the workers never act on a terminal's Ctrl+C, and this process never
    ignores it (ignored while the workers were spawned, a Ctrl+C in those seconds was
    lost on a busy machine)."""
    import signal

    import psutil

    from hydroilqr.studies.cluster import _spawned_pids, open_client

    handler, mask = signal.getsignal(signal.SIGINT), signal.pthread_sigmask(signal.SIG_BLOCK, [])
    # (earlier tests in this process may have left spawns of their own: only the new ones)
    before = {child.pid for child in psutil.Process().children()}
    client, cluster = open_client(None, workers=1)
    try:
        assert signal.getsignal(signal.SIGINT) is handler  # (never ignored meanwhile)
        assert signal.pthread_sigmask(signal.SIG_BLOCK, []) == mask
        pids = _spawned_pids(psutil.Process(), before)
        assert pids
        for pid in pids:
            status = Path(f"/proc/{pid}/status").read_text()
            blocked = int(
                next(ln for ln in status.splitlines() if ln.startswith("SigBlk")).split()[1], 16
            )
            assert blocked & (1 << (signal.SIGINT - 1))
    finally:
        client.close()
        cluster.close()
