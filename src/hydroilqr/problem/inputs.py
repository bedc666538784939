"""Bounded reading of the files a user names (task files, --config, extends targets, initial
guesses, reference runs, checkpoints): each must be a regular file under a size cap, checked
before a byte is read, and a refusal names the file and the problem, never its content.

Also the memory estimate of a horizon (``check_memory``), refused before anything is
allocated when it would not fit."""

from __future__ import annotations

import html
import os
import re
import stat
import zipfile
from pathlib import Path

from hydroilqr.problem.errors import ConfigError

MiB = 1 << 20
MAX_YAML_BYTES = 1 * MiB  # task files, --config files, extends targets
MAX_TABLE_BYTES = 16 * MiB  # an initial-guess CSV/.npz at least may be this large
BYTES_PER_TABLE_NUMBER = 64  # a CSV number with its separator, generously
MAX_ARRAY_FILE_BYTES = 2048 * MiB  # a solved run's solution.npz, a checkpoint, a sweep point
MAX_JSON_BYTES = 256 * MiB  # a run's summary.json
MAX_MODEL_BYTES = 64 * MiB  # a model file (SDFormat/URDF/MJCF text) named by path
MAX_MESH_BYTES = 256 * MiB  # a mesh a model file names (OBJ, glTF, VTK, STL, ...)

# Environment variable: the memory (bytes) a solve may plan to hold; default a fraction of
# the memory available when the check runs.
MEMORY_LIMIT_ENV = "HYDROILQR_MEMORY_LIMIT"
MEMORY_FRACTION = 0.75


def _config_error(msg: str) -> Exception:
    return ConfigError(msg)


def _kind(mode: int) -> str:
    for test, name in (
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISFIFO, "a named pipe"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def _size_text(n: int) -> str:
    return f"{n / MiB:.1f} MiB" if n >= MiB else f"{n} bytes"


def _check_stat(st: os.stat_result, path: Path, what: str, max_bytes: int) -> None:
    if not stat.S_ISREG(st.st_mode):
        raise _config_error(f"{what} {path}: {_kind(st.st_mode)}, not a regular file")
    if st.st_size > max_bytes:
        raise _config_error(
            f"{what} {path}: {_size_text(st.st_size)}, more than the {_size_text(max_bytes)} "
            "such a file may have"
        )


def check_file(path: str | Path, what: str, max_bytes: int) -> Path:
    """``path`` if it is a regular file (symlinks followed) of at most ``max_bytes``;
    ConfigError naming it and the problem otherwise. For files another library reads."""
    path = Path(path)
    try:
        st = os.stat(path)
    except OSError as e:
        raise _config_error(f"{what} {path}: {e.strerror or 'cannot be read'}") from None
    _check_stat(st, path, what, max_bytes)
    return path


def read_bounded(path: str | Path, what: str, max_bytes: int) -> bytes:
    """The bytes of ``path``, a regular file of at most ``max_bytes``; ConfigError naming
    the file and the problem otherwise (checked on the open file, before reading; a FIFO is
    never waited on)."""
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as e:
        raise _config_error(f"{what} {path}: {e.strerror or 'cannot be opened'}") from None
    try:
        _check_stat(os.fstat(fd), path, what, max_bytes)
        chunks, total = [], 0
        while True:
            chunk = os.read(fd, min(MiB, max_bytes + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
            if total > max_bytes:  # it grew while being read
                raise _config_error(
                    f"{what} {path}: more than the {_size_text(max_bytes)} such a file may have"
                )
        return b"".join(chunks)
    except OSError as e:
        raise _config_error(f"{what} {path}: {e.strerror or 'cannot be read'}") from None
    finally:
        os.close(fd)


def read_text_bounded(path: str | Path, what: str, max_bytes: int = MAX_YAML_BYTES) -> str:
    """``read_bounded`` decoded as UTF-8 (ConfigError naming the byte offset otherwise)."""
    data = read_bounded(path, what, max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise _config_error(f"{what} {path}: not UTF-8 text (byte {e.start})") from None


def check_npz(path: str | Path, what: str, max_bytes: int) -> Path:
    """``check_file`` for an .npz archive, and its arrays' uncompressed sizes together at
    most ``max_bytes`` too (a small compressed file can declare huge arrays)."""
    path = check_file(path, what, max_bytes)
    try:
        with zipfile.ZipFile(path) as z:
            total = sum(i.file_size for i in z.infolist())
    except (OSError, zipfile.BadZipFile, ValueError):
        return path  # not an archive: np.load reports it
    if total > max_bytes:
        raise _config_error(
            f"{what} {path}: its arrays hold {_size_text(total)} uncompressed, more than the "
            f"{_size_text(max_bytes)} such a file may have"
        )
    return path


def table_cap(rows: int, columns: int) -> int:
    """Size cap of a file holding a [rows, columns] table of numbers (CSV or .npz)."""
    return max(MAX_TABLE_BYTES, BYTES_PER_TABLE_NUMBER * max(rows, 1) * max(columns, 1))


# --------------------------------------------------------------------------------------------
# Memory of a horizon
# --------------------------------------------------------------------------------------------


def horizon_bytes(steps: int, nx: int, nu: int) -> int:
    """Bytes one solve over ``steps`` time steps holds at least (float64): the trajectory
    X [N+1, nx] and U [N, nu] with a line-search candidate of each, gains K [N, nu, nx] and
    kappa [N, nu], partials A [N, nx, nx] and B [N, nx, nu] (and their kept copy for reuse),
    plus a per-step allowance for the bookkeeping of each step (contact records, Python
    objects)."""
    per_step = 2 * (nx + nu) + nu * nx + nu + 2 * (nx * nx + nx * nu)
    return 8 * steps * per_step + PER_STEP_OVERHEAD * steps


PER_STEP_OVERHEAD = 4096  # bytes of per-step bookkeeping besides the arrays (contacts, objects)


def available_memory() -> int:
    """Bytes of memory this process may plan to use: the environment's HYDROILQR_MEMORY_LIMIT
    if set, else a fraction of the available (or physical) memory."""
    env = os.environ.get(MEMORY_LIMIT_ENV, "").strip()
    if env:
        try:
            return int(float(env))
        except ValueError:
            raise _config_error(f"{MEMORY_LIMIT_ENV}={env!r}: expected a number of bytes") from None
    avail = 0
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    if not avail:
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            return 1 << 62  # unknown: no refusal
    return int(MEMORY_FRACTION * avail)


def check_memory(steps: int, nx: int, nu: int, what: str, extra: int = 0) -> None:
    """ConfigError if a solve over ``steps`` time steps (``what`` names them), plus ``extra``
    bytes, would need more memory than ``available_memory``."""
    need = horizon_bytes(steps, nx, nu) + extra
    have = available_memory()
    if need > have:
        raise _config_error(
            f"{what}: {steps} time steps of nx={nx}, nu={nu} need about {need / MiB:,.0f} MiB "
            f"of memory; {have / MiB:,.0f} MiB can be used (fewer steps, or a longer time step)"
        )


# --------------------------------------------------------------------------------------------
# Files a model file names
# --------------------------------------------------------------------------------------------

# A start or end tag: its name and attributes (no "<" inside, so a scan stays linear).
_XML_TAG = re.compile(r"<(/?)([A-Za-z_:][^\s/<>]*)((?:\"[^\"<]*\"|'[^'<]*'|[^<>\"'])*)>")
_XML_ATTR = re.compile(r"([^\s=/]+)\s*=\s*(?:\"([^\"]*)\"|'([^']*)')")
_XML_SKIP = (("<!--", "-->"), ("<?", "?>"), ("<!", ">"))


def _xml_events(text: str):
    """("start"|"empty"|"end", local tag name, attributes) and ("text", str) of an XML
    document, read leniently as Drake's parser (tinyxml2) reads one: namespace prefixes need
    no declaration (``drake:`` tags), comments end at the first ``-->``, no error is raised."""
    i, n = 0, len(text)
    while i < n:
        lt = text.find("<", i)
        if lt < 0:
            yield "text", html.unescape(text[i:])
            return
        if lt > i:
            yield "text", html.unescape(text[i:lt])
        if text.startswith("<![CDATA[", lt):
            end = text.find("]]>", lt)
            yield "text", text[lt + 9 : n if end < 0 else end]
            i = n if end < 0 else end + 3
            continue
        close = next((c for o, c in _XML_SKIP if text.startswith(o, lt)), None)
        if close is not None:
            end = text.find(close, lt + 2)
            i = n if end < 0 else end + len(close)
            continue
        m = _XML_TAG.match(text, lt)
        if m is None:
            yield "text", "<"
            i = lt + 1
            continue
        name, attrs = m[2].rsplit(":", 1)[-1], m[3]
        kind = "end" if m[1] else ("empty" if attrs.rstrip().endswith("/") else "start")
        values = {a: html.unescape(b if b or not c else c) for a, b, c in _XML_ATTR.findall(attrs)}
        yield kind, name, values
        i = m.end()


def model_file_references(text: str) -> list[tuple[str, bool]]:
    """(reference, is an included model) of every mesh and include a URDF, SDFormat or MJCF
    document names: ``<mesh filename=...>`` (URDF), ``<mesh><uri>`` and ``<include><uri>``
    (SDFormat), ``<mesh file=...>`` and ``<include file=...>`` (MJCF, under its
    ``<compiler meshdir=...>``). Read leniently (``_xml_events``): a document Drake would
    parse is never skipped for a namespace it does not declare."""
    refs: list[tuple[str, bool]] = []
    stack: list[str] = []
    uri: list[str] | None = None
    meshdir = ""
    for kind, *rest in _xml_events(text):
        if kind == "text":
            if uri is not None:
                uri.append(rest[0])
            continue
        name, attrs = rest
        if kind == "end":
            if name == "uri" and uri is not None and len(stack) >= 2:
                parent = stack[-2]
                if "".join(uri).strip():
                    refs.append(("".join(uri).strip(), parent == "include"))
            uri = None
            if name in stack:
                del stack[len(stack) - 1 - stack[::-1].index(name) :]
            continue
        if name == "compiler":
            meshdir = attrs.get("meshdir") or attrs.get("assetdir") or meshdir
        elif name == "mesh":
            refs += [(attrs[a], False) for a in ("filename",) if attrs.get(a)]
            if attrs.get("file"):
                refs.append((os.path.join(meshdir, attrs["file"]), False))
        elif name == "include" and attrs.get("file"):
            refs.append((attrs["file"], True))
        if kind == "start":
            stack.append(name)
            if name == "uri" and len(stack) >= 2 and stack[-2] in ("mesh", "include"):
                uri = []
    return refs
