"""Command-line interface: ``hydroilqr <command> ...`` (see ``hydroilqr --help``).

Every command reports bad input as one line on stderr and exits non-zero; set
HYDROILQR_DEBUG=1 to see tracebacks. Warnings of a run also go to stderr (``warn``), its report
to stdout.
"""

from __future__ import annotations

import argparse
import codecs
import contextlib
import importlib.abc
import importlib.util
import os
import shlex
import signal
import sys
import threading

from hydroilqr import __version__
from hydroilqr.problem.errors import ConfigError

# Also importable from here, as before; loaded on first use (importing hydroilqr.cli loads
# nothing heavy: ``main`` loads the commands with Ctrl+C held, see ``_interrupts_held``).
_COMMON = ("add_task_args", "console", "err_console", "load_task_from_args", "task_name_from_args")
_COMMON += ("warn",)


def __getattr__(name: str):
    if name in _COMMON:
        from hydroilqr.cli import common

        return getattr(common, name)
    raise AttributeError(f"module 'hydroilqr.cli' has no attribute {name!r}")


def commands() -> dict:
    """The commands, in the order ``hydroilqr --help`` lists them: name -> its module in
    hydroilqr.cli, which has HELP (one line), setup(parser) (the command's arguments) and
    run(args) -> exit code. A new command: one module, one import and one entry here.
    (Imported on first use: they import Drake and Dask.)"""
    from hydroilqr.cli import (
        bench,
        check,
        mpc,
        playback,
        replay,
        results,
        robustness,
        schema,
        search,
        solve,
        sweep,
        tasks,
    )

    return {
        "tasks": tasks,
        "solve": solve,
        "search": search,
        "check": check,
        "sweep": sweep,
        "playback": playback,
        "replay": replay,
        "bench": bench,
        "mpc": mpc,
        "results": results,
        "robustness": robustness,
        "schema": schema,
    }


class _Parser(argparse.ArgumentParser):
    """Argument errors as one line (``hydroilqr: error: ...``), like every other error."""

    def error(self, message):
        self.exit(2, f"hydroilqr: error: {message} (see `{self.prog} --help`)\n")


def _version_line() -> str:
    from hydroilqr.io.environment import environment

    e = environment()
    return (
        f"hydroilqr {__version__} (code {e['code'] or 'unknown'}; drake {e['drake']}, "
        f"numpy {e['numpy']}, "
        f"OpenBLAS kernels {e['blas_core'] or 'unknown'}, Python {e['python']}, "
        f"{e['cores']} cores)"
    )


class _VersionAction(argparse.Action):
    """--version, computed only when asked (it runs git and reads the BLAS library)."""

    def __init__(self, option_strings, dest, **kwargs):
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        print(_version_line())
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="hydroilqr",
        description="Contact-implicit trajectory optimization: iLQR over Drake's hydroelastic "
        "contact.",
    )
    parser.add_argument(
        "--version",
        action=_VersionAction,
        help="the version and what decides the last bits of a result (drake, numpy, BLAS)",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for name, module in commands().items():
        p = sub.add_parser(name, help=module.HELP)
        module.setup(p)
        p.set_defaults(func=module.run)
    return parser


def _join_negative_values(argv: list[str]) -> list[str]:
    """``--values -5,1e6`` -> ``--values=-5,1e6`` (argparse takes "-5,1e6" for an option);
    the same for ``--push -1:cart:...``."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        if argv[i] in ("--values", "--push") and i + 1 < len(argv) and argv[i + 1].startswith("-"):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out


def _escape_unencodable_output() -> None:
    """Output streams that cannot encode every character (PYTHONIOENCODING=ascii, or
    PYTHONUTF8=0 under LANG=C) print the units and symbols the messages use (μ, ε, τ, ū, ≥)
    as escapes such as ``\\u03bc`` instead of failing on them."""

    for stream in (sys.stdout, sys.stderr):
        encoding = getattr(stream, "encoding", None)
        if not encoding or getattr(stream, "errors", None) != "strict":
            continue
        try:
            if codecs.lookup(encoding).name != "utf-8":
                stream.reconfigure(errors="backslashreplace")
        except (AttributeError, LookupError, ValueError, OSError):
            pass


def _first_line(e: object) -> str:
    """The first line of an error's text (at most 500 characters)."""
    text = str(e).strip()
    return text.splitlines()[0][:500] if text else ""


@contextlib.contextmanager
def _interrupts_held():
    """Ctrl+C (SIGINT) inside the block is held until it ends: the list it yields is then
    non-empty. An import cut short by KeyboardInterrupt can leave a half-initialized
    extension behind (pydrake's then fails as ImportError) or print a traceback."""
    held: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield held
        return
    previous = signal.getsignal(signal.SIGINT)
    if previous is not signal.default_int_handler:  # (ignored, or the caller's own)
        yield held
        return
    signal.signal(signal.SIGINT, lambda *_: held.append(1))
    try:
        yield held
    finally:
        signal.signal(signal.SIGINT, previous)


class _DrakeLoadsWhole(importlib.abc.MetaPathFinder):
    """Loads pydrake (its first import, wherever a command makes it) with Ctrl+C held, and
    raises the KeyboardInterrupt once it is loaded: cut short, pydrake prints a 50-line
    stack from C++ and fails as ImportError."""

    def find_spec(self, fullname, path, target=None):
        if fullname != "pydrake":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        load = spec.loader.exec_module

        def exec_module(module):
            with _interrupts_held() as held:
                load(module)
            if held:
                raise KeyboardInterrupt

        spec.loader.exec_module = exec_module
        return spec


def main(argv: list[str] | None = None) -> int:
    _escape_unencodable_output()
    if "pydrake" not in sys.modules and not any(
        isinstance(f, _DrakeLoadsWhole) for f in sys.meta_path
    ):
        sys.meta_path.insert(0, _DrakeLoadsWhole())
    with _interrupts_held() as held:
        commands()  # imports numpy, Dask and Drake
    if held:
        print("hydroilqr: interrupted", file=sys.stderr)
        return 130
    parser = build_parser()
    argv = _join_negative_values(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    if isinstance(getattr(args, "out", None), str) and not args.out.strip():
        print("hydroilqr: error: --out: an empty directory name", file=sys.stderr)
        return 2

    # recorded in the results as environment.command
    args.command_line = shlex.join(["hydroilqr", *argv])
    try:
        return _run(args)
    except BaseException as e:  # noqa: BLE001 - the promise is one line, never a traceback
        code = _exit_code(e)
        if code is None:
            raise
        return code


def _run(args) -> int:
    """Runs the command; a failed one leaves no empty results directory, and none leaves its
    directories locked (nor their lock files behind)."""
    try:
        return int(args.func(args) or 0)
    except BaseException:
        if "hydroilqr.output.report" in sys.modules:  # (else no output directory was made)
            sys.modules["hydroilqr.output.report"].discard_empty_outputs()
        raise
    finally:
        if "hydroilqr.output.report" in sys.modules:
            sys.modules["hydroilqr.output.report"].release_locks()


def _exit_code(e: BaseException) -> int | None:
    """Prints the one line that reports ``e`` on stderr and returns the exit code; None for
    what is raised on (SystemExit, and any error under HYDROILQR_DEBUG=1)."""
    if isinstance(e, KeyboardInterrupt) or _caused_by_interrupt(e):
        detail = f": {e}" if isinstance(e, KeyboardInterrupt) and str(e) else ""
        print(f"hydroilqr: interrupted{detail}", file=sys.stderr)
        return 130
    if os.environ.get("HYDROILQR_DEBUG"):
        return None
    if isinstance(e, SystemExit):  # e.g. from pydrake: its message, as one line
        return _system_exit_code(e)
    if not isinstance(e, Exception):
        return None
    code, line = _error_line(e)
    print(line, file=sys.stderr)
    return code


def _caused_by_interrupt(e: BaseException) -> bool:
    """True for an error raised because of a Ctrl+C: pydrake's import cut short fails as
    ImportError caused by a KeyboardInterrupt."""
    seen: set[int] = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, KeyboardInterrupt):
            return True
        e = e.__cause__ or e.__context__
    return False


def _system_exit_code(e: SystemExit) -> int | None:
    """None for a SystemExit that carries an exit code; 1 (after its message, as one line)
    for one that carries a message."""
    if isinstance(e.code, int) or e.code is None:
        return None
    print(f"hydroilqr: error: {_first_line(e.code)}", file=sys.stderr)
    return 1


def _error_line(e: Exception) -> tuple[int, str]:
    """The exit code for ``e`` and the one line that reports it."""
    if isinstance(e, ConfigError):
        return 2, f"hydroilqr: error: {e}"
    plant = sys.modules.get("hydroilqr.model.plant")  # (not loaded: no simulation ran)
    if plant is not None and isinstance(e, plant.SimulationError):
        return 3, f"hydroilqr: simulation failed: {e}"
    if isinstance(e, OSError):  # e.g. a full disk or a directory made read-only during the run
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        return 1, f"hydroilqr: error: {where}{e.strerror or e}"
    if isinstance(e, RuntimeError) and str(e).lstrip().startswith("Failure at "):
        return 3, f"hydroilqr: Drake failure: {_first_line(e)}"
    return 1, (
        f"hydroilqr: internal error: {type(e).__name__}: {_first_line(e)} "
        "(set HYDROILQR_DEBUG=1 for a traceback)"
    )


if __name__ == "__main__":
    sys.exit(main())
