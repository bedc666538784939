"""Task files: built-in names, bounded YAML reading (unique keys, no alias bombs, 1e6 a
number), ``extends`` with its paths anchored, and the merging of layers."""

from __future__ import annotations

import copy
import re
from collections.abc import Hashable
from pathlib import Path
from typing import Any

import yaml

from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.inputs import read_text_bounded
from hydroilqr.problem.paths import anchor_paths
from hydroilqr.problem.typed import MAX_DEPTH, plain_data

TASKS_DIR = Path(__file__).parent.parent / "tasks"


def task_file(name_or_path: str) -> Path:
    """Built-in task name or a path to a task YAML file."""
    if not isinstance(name_or_path, (str, Path)) or "\n" in str(name_or_path):
        raise ConfigError(
            "expected a built-in task name or a task file path (for YAML text: "
            "Task.from_dict(yaml.safe_load(text)))"
        )
    p = Path(name_or_path)
    builtin = TASKS_DIR / f"{name_or_path}.yaml"
    if p.is_dir() and builtin.exists():
        return builtin  # e.g. a run directory named like the task (--out cartpole-wall)
    if p.suffix in (".yaml", ".yml") or p.exists():
        if not p.exists():
            raise ConfigError(f"task file {name_or_path}: no such file")
        if p.is_dir():
            raise ConfigError(f"task file {name_or_path}: a directory, not a task YAML file")
        return p
    if not builtin.exists():
        raise ConfigError(
            f"unknown task {name_or_path!r} (built-in tasks: {', '.join(list_tasks())})"
        )
    return builtin


def list_tasks() -> list[str]:
    return sorted(p.stem for p in TASKS_DIR.glob("*.yaml") if not p.stem.startswith("_"))


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that rejects a key given twice in one mapping (YAML keeps the last silently)."""

    def construct_mapping(self, node, deep=False):
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            if not isinstance(key, Hashable):
                raise yaml.constructor.ConstructorError(
                    None,
                    None,
                    "a key that is a list or a mapping (keys are names)",
                    key_node.start_mark,
                )
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None,
                    None,
                    f"key {key!r} given twice (first on line {seen[key] + 1})",
                    key_node.start_mark,
                )
            seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep)

    def compose_document(self):
        """The document's node graph, refused (before anything is built from it) when its
        aliases would expand to more than MAX_YAML_NODES nodes, or refer to themselves."""
        node = super().compose_document()
        if node is not None and self.anchors_seen:
            n = _expanded_nodes(node)
            if n < 0 or n > MAX_YAML_NODES:
                problem = (
                    "an alias refers to a node that contains it"
                    if n < 0
                    else f"its aliases expand to more than {MAX_YAML_NODES} values"
                )
                raise yaml.composer.ComposerError(None, None, problem, node.start_mark)
        return node

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            self.anchors_seen = True
        return super().compose_node(parent, index)

    anchors_seen = False


MAX_YAML_NODES = 100_000  # nodes of a YAML document with its aliases expanded


def _expanded_nodes(root) -> int:
    """Nodes of the composed YAML graph ``root`` counted as if every alias were a copy of
    its anchor (what a deep copy or a JSON dump of the loaded data holds); counted once per
    distinct node, so an alias bomb is measured without being expanded. -1 for a recursive
    alias (a node inside itself)."""
    size: dict[int, int] = {}
    on_path: set[int] = set()
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        children = []
        if isinstance(node, yaml.SequenceNode):
            children = node.value
        elif isinstance(node, yaml.MappingNode):
            children = [n for pair in node.value for n in pair]
        if done:
            on_path.discard(key)
            size[key] = min(1 + sum(size[id(c)] for c in children), 1 << 62)
            continue
        if key in size:
            continue
        if key in on_path:
            return -1
        on_path.add(key)
        stack.append((node, True))
        for c in children:
            if id(c) in on_path:
                return -1
            if id(c) not in size:
                stack.append((c, False))
    return size[id(root)]


# YAML 1.1 (PyYAML) reads 1e6 (no dot) as the *string* "1e6"; read it as a number, as YAML 1.2
# and every reader of a task file would.
_UniqueKeyLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9][0-9_]*)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def yaml_value(text: str) -> Any:
    """A value given on the command line or in an override, read as YAML (1e6 is a number);
    yaml.YAMLError also for nesting too deep to read."""
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except RecursionError:
        raise yaml.YAMLError(f"nested more than {MAX_DEPTH} levels deep") from None


KEY_LIKE = re.compile(r"^[A-Za-z_][A-Za-z0-9_.\-]{0,63}$")  # shown in messages as typed


def _yaml_problem(e: yaml.YAMLError, text: str) -> str:
    """ ": line L: what is wrong" of a YAML error, on one line (a reader's error, such as a NUL
    byte, by the line of its character)."""
    mark = getattr(e, "problem_mark", None)
    line = mark.line + 1 if mark is not None else None
    if isinstance(e, yaml.reader.ReaderError):
        line = text.count("\n", 0, e.position) + 1
    problem = getattr(e, "problem", None) or str(e) or "malformed YAML"
    if isinstance(e, yaml.reader.ReaderError):
        char = f" #x{e.character:04x}" if isinstance(e.character, int) else ""
        problem = f"unacceptable character{char} (a YAML file holds text only)"
    problem = " ".join(str(problem).split())
    return (f": line {line}" if line is not None else "") + f": {problem}"


def load_raw(path: Path, what: str = "task file", _chain: tuple[Path, ...] = ()) -> dict[str, Any]:
    if path.resolve() in _chain:
        loop = " -> ".join(p.name for p in (*_chain, path.resolve()))
        raise ConfigError(f"{what} {path}: `extends` loops back on itself ({loop})")
    text = read_text_bounded(path, what)  # a regular file of at most 1 MiB
    try:
        data = yaml_value(text)
    except yaml.YAMLError as e:
        raise ConfigError(f"{what} {path}{_yaml_problem(e, text)}") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{what} {path}: expected a mapping at the top level")
    for k, v in data.items():
        if isinstance(k, str) and KEY_LIKE.match(k):
            plain_data(v, k)  # (nesting a task cannot mean: one line naming the key)
    for k in data:
        if not (isinstance(k, str) and KEY_LIKE.match(k)):  # not quoted: not a task file?
            raise ConfigError(
                f"{what} {path}: a top-level key that is no task setting (is it a task file?)"
            )
    return extend(data, path.parent, f"{what} {path}", (*_chain, path.resolve()))


def extend(data: dict[str, Any], directory: Path, where: str, chain=()) -> dict[str, Any]:
    """``data`` merged over the file its ``extends:`` names (relative to ``directory``, or a
    built-in task's name), if any: `extends: other.yaml` shares a base file between related
    tasks."""
    base = data.pop("extends", None)
    if base is None:
        return data
    if not isinstance(base, str):
        raise ConfigError(f"{where}: extends: expected one file name, got {base!r}")
    base_path = (directory / base).resolve()
    builtin = TASKS_DIR / f"{base}.yaml"
    if not base_path.exists() and "/" not in base and builtin.exists():
        base_path = builtin  # a built-in task by name: extends: cartpole-wall
    if not base_path.exists():
        raise ConfigError(f"{where}: extends: no such file {base_path}")
    parent = load_raw(base_path, _chain=chain)
    if base_path.parent != directory.resolve():
        anchor_paths(parent, base_path.parent)
    if isinstance(parent.get("smoke"), dict) and isinstance(data.get("smoke"), dict):
        # the child's smoke length wins over the parent's, as at the top level
        parent["smoke"] = without_other_length(parent["smoke"], data["smoke"])
    return merge(without_other_length(parent, data), data)


def without_other_length(below: dict[str, Any], above: dict[str, Any]) -> dict[str, Any]:
    """``below`` minus its horizon or num_steps when the layer ``above`` gives the other one:
    the upper layer's trajectory length wins (extends, --config, smoke)."""
    below = dict(below)
    if above.get("horizon") is not None and "num_steps" not in above:
        below.pop("num_steps", None)
    if above.get("num_steps") and "horizon" not in above:
        below.pop("horizon", None)
    return below


def merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out
