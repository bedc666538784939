"""Every file a command writes goes through output/ (issue 50, item 5): no module outside
output/ and io/ opens a file for writing, saves arrays with numpy, dumps JSON into a file,
writes a path's text or bytes, or calls io/'s atomic writers itself. The studies and the
solver compute data; output/ writes it on ``write_set``'s skeleton."""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[2] / "src" / "hydroilqr"

WRITERS = ("output", "io")  # the packages that write files
# Solution.save: the library's own save of a plan (``sol.save(path)``, README); write_solve
# calls it into its stage. The one writer below output/ on purpose.
ALLOWED = {("solver/solution.py", "atomic_savez")}

NUMPY_SAVERS = {"save", "savez", "savez_compressed", "savetxt"}
ATOMIC = {"atomic_write", "atomic_savez"}


def _constant_text(node: ast.AST | None) -> str | None:
    return node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) else None


def _open_mode(call: ast.Call, position: int) -> str | None:
    """The mode of ``open(file, mode)`` (position 1) or ``path.open(mode)`` (position 0)."""
    if len(call.args) > position:
        return _constant_text(call.args[position])
    return next((_constant_text(k.value) for k in call.keywords if k.arg == "mode"), None)


def _write_kind(call: ast.Call) -> str | None:
    """What file write ``call`` is, or None if it writes no file."""
    f = call.func
    if isinstance(f, ast.Name):
        name, owner = f.id, None
    elif isinstance(f, ast.Attribute):
        name = f.attr
        owner = f.value.id if isinstance(f.value, ast.Name) else ""
    else:
        return None
    if name == "open" and owner != "os":  # open(p, "w"), io.open, Path(p).open("a")
        plain = owner in (None, "io", "builtins")
        mode = _open_mode(call, 1 if plain else 0)
        return f"open(..., {mode!r})" if mode and set(mode) & set("wax+") else None
    if owner in ("np", "numpy") and name in NUMPY_SAVERS:
        return f"np.{name}"
    if owner == "json" and name == "dump":
        return "json.dump"
    if owner == "yaml" and name in ("dump", "safe_dump") and len(call.args) > 1:
        return f"yaml.{name} to a stream"
    if owner is not None and name in ("write_text", "write_bytes", "tofile"):
        return f".{name}"
    if name in ATOMIC:
        return name
    return None


def file_writes(src: Path) -> list[str]:
    """``module:line: kind`` of every file write outside output/ and io/ (ALLOWED aside)."""
    found = []
    for f in sorted(src.rglob("*.py")):
        rel = f.relative_to(src)
        if rel.parts[0] in WRITERS:
            continue
        calls = [
            n for n in ast.walk(ast.parse(f.read_text(encoding="utf-8"))) if isinstance(n, ast.Call)
        ]
        for node in sorted(calls, key=lambda n: (n.lineno, n.col_offset)):
            kind = _write_kind(node)
            if kind and (rel.as_posix(), kind) not in ALLOWED:
                found.append(f"{rel.as_posix()}:{node.lineno}: {kind}")
    return found


def test_no_module_outside_output_and_io_writes_a_file():
    assert file_writes(SRC) == []


def test_every_kind_of_write_is_caught(tmp_path):
    (tmp_path / "studies").mkdir()
    (tmp_path / "output").mkdir()
    lines = [
        "import json, numpy as np, yaml",
        "from pathlib import Path",
        "from hydroilqr.io.files import atomic_write",
        "with open('a.log', 'a') as fh: fh.write('x')",
        "with open('t.csv', mode='w') as fh: json.dump({}, fh)",
        "Path('p').open('wb')",
        "np.savez('x.npz', a=1)",
        "np.save('x.npy', 1)",
        "Path('s.json').write_text('{}')",
        "Path('b').write_bytes(b'')",
        "yaml.safe_dump({}, open('y.yaml', 'x'))",
        "atomic_write('r.json', '{}')",
        "open('read.txt').read()",  # reads: not caught
        "open('read.bin', 'rb').read()",
        "json.dumps({})",
    ]
    (tmp_path / "studies" / "study.py").write_text("\n".join(lines) + "\n")
    (tmp_path / "output" / "writer.py").write_text("\n".join(lines) + "\n")  # allowed there
    kinds = [w.split(": ", 1)[1] for w in file_writes(tmp_path)]
    assert kinds == [
        "open(..., 'a')",
        "open(..., 'w')",
        "json.dump",
        "open(..., 'wb')",
        "np.savez",
        "np.save",
        ".write_text",
        ".write_bytes",
        "yaml.safe_dump to a stream",
        "open(..., 'x')",
        "atomic_write",
    ]
