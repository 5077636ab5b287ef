"""Reading YAML files that may be hostile: bounded size, depth and aliases, no duplicate keys.

``yaml.safe_load`` constructs no arbitrary objects, but it still accepts inputs that hurt: a
"billion laughs" file (aliases of aliases) expands to gigabytes once validated and printed, a
few thousand nested brackets end in ``RecursionError``, a binary file in ``UnicodeDecodeError``,
and a key given twice silently keeps the second value. ``load_yaml_text`` refuses all of them
with a ``YamlLimitError`` that names the line, what was expected and what was found, before
anything is built from the document.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

MAX_FILE_BYTES = 1 << 20  # a vehicle file is ~20 kB; a megabyte is generous
MAX_DEPTH = 32  # a vehicle nests 5 levels deep
MAX_ALIASES = 200  # iss_rs uses ~30 aliases for shared mode shapes
MAX_NODES = 200_000  # nodes as written in the file
MAX_EXPANDED_NODES = 1_000_000  # nodes once aliases are expanded (iss_rs: ~3,000)


class YamlLimitError(ValueError):
    """``field`` (``line N`` or ``""``), ``expected`` and ``found`` of a refused document."""

    def __init__(self, field: str, expected: str, found: str) -> None:
        super().__init__(f"{field}: expected {expected}, got {found}")
        self.field, self.expected, self.found = field, expected, found


def _line(node_or_mark: Any) -> str:
    mark = getattr(node_or_mark, "start_mark", node_or_mark)
    return f"line {mark.line + 1}" if mark is not None else ""


class _BoundedLoader(yaml.SafeLoader):
    """A safe loader that counts depth, aliases and nodes while composing and refuses
    duplicate mapping keys while constructing."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0
        self._aliases = 0
        self._nodes = 0

    def compose_node(self, parent: Any, index: Any) -> Any:  # noqa: D102 - PyYAML hook
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > MAX_ALIASES:
                raise YamlLimitError(_line(event), f"at most {MAX_ALIASES} aliases",
                                     f"more ({event.anchor!r} is number {self._aliases})")
        self._nodes += 1
        if self._nodes > MAX_NODES:
            raise YamlLimitError(_line(event), f"at most {MAX_NODES} nodes", "more")
        self._depth += 1
        if self._depth > MAX_DEPTH:
            raise YamlLimitError(_line(event), f"nesting at most {MAX_DEPTH} levels deep",
                                 "deeper")
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node: Any, deep: bool = False) -> Any:  # noqa: D102
        seen: dict[Any, Any] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                hash(key)
            except TypeError:
                raise YamlLimitError(_line(key_node), "a scalar mapping key",
                                     type(key).__name__) from None
            if key in seen:
                raise YamlLimitError(
                    _line(key_node), f"each key once in a mapping (first at {_line(seen[key])})",
                    f"{key!r} again")
            seen[key] = key_node
        return super().construct_mapping(node, deep=deep)



def expanded_size(root: Any) -> float:
    """Nodes of the document once every alias is replaced by a copy of its anchor: what
    validating or printing it costs. Aliases share their node, so this is computed once per
    node (memoised), in time linear in the file, however large the expansion."""
    memo: dict[int, float] = {}
    stack: list[tuple[Any, bool]] = [(root, False)]
    while stack:  # post-order without recursion: children before their parent
        node, ready = stack.pop()
        if id(node) in memo:
            continue
        kids = _children(node)
        if ready:
            memo[id(node)] = 1.0 + sum(memo[id(c)] for c in kids)
        else:
            stack.append((node, True))
            stack.extend((c, False) for c in kids if id(c) not in memo)
    return memo[id(root)]


def _children(node: Any) -> list[Any]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [x for kv in node.value for x in kv]
    return []


def decode_text(data: bytes) -> str:
    """UTF-8 text, or ``YamlLimitError`` naming the first bad byte (binary files too)."""
    if b"\x00" in data[:8192]:
        raise YamlLimitError("", "a UTF-8 text file", "a binary file (NUL bytes)")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise YamlLimitError(f"line {line}", "UTF-8 text",
                             f"byte 0x{data[exc.start]:02x} at offset {exc.start}") from None


def load_yaml_text(text: str) -> Any:
    """Parse one YAML document under the limits above (``YamlLimitError`` or
    ``yaml.YAMLError`` on refusal)."""
    if len(text) > MAX_FILE_BYTES:
        raise YamlLimitError("", f"at most {MAX_FILE_BYTES} characters", f"{len(text)}")
    loader = _BoundedLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        size = expanded_size(node)
        if size > MAX_EXPANDED_NODES:
            raise YamlLimitError("", f"at most {MAX_EXPANDED_NODES} values once aliases are "
                                 "expanded", f"{size:.3g}" if size < 1e300 else "more")
        return loader.construct_document(node)
    except RecursionError:  # a structure deeper than Python's own stack, below MAX_DEPTH
        raise YamlLimitError("", f"nesting at most {MAX_DEPTH} levels deep", "deeper") from None
    finally:
        loader.dispose()


def read_mapping(path: Path) -> dict[str, Any]:
    """A configuration file's top-level mapping, or ``YamlLimitError`` (field, expected,
    found) for every way it can fail: no such file, a directory, unreadable, over a limit,
    not YAML, not a mapping. Each loader renders that as its own one-line error."""
    try:
        data = read_yaml_file(path)
    except FileNotFoundError:
        raise YamlLimitError("", "an existing file", "no such file") from None
    except IsADirectoryError:
        raise YamlLimitError("", "a file", "a directory") from None
    except OSError as exc:
        raise YamlLimitError("", "a readable file", exc.strerror or str(exc)) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f"line {mark.line + 1}" if mark else "?"
        raise YamlLimitError(line, "valid YAML", repr(getattr(exc, "problem", str(exc)))) \
            from None
    if not isinstance(data, dict):
        raise YamlLimitError("", "a YAML mapping at the top level", repr(type(data).__name__))
    return data


def read_yaml_file(path: Path) -> Any:
    """Read and parse ``path`` under the limits (``OSError`` passes through)."""
    size = path.stat().st_size
    if size > MAX_FILE_BYTES:
        raise YamlLimitError("", f"a file of at most {MAX_FILE_BYTES} bytes", f"{size} bytes")
    with path.open("rb") as f:
        data = f.read(MAX_FILE_BYTES + 1)
    return load_yaml_text(decode_text(data))
