"""YAML for configuration files a person writes: plain data only, bounded in size.

``yaml.safe_load`` builds no objects, but it still expands anchors and aliases (a 1.2 KB
"billion laughs" document stalls anything that walks the result), accepts any nesting depth and
any explicit tag it knows, and keeps the last of two equal keys. :func:`load_yaml` refuses all of
these with ``BadInputError`` naming the source and the line, so a configuration is exactly the
mappings, lists and scalars it shows. No ROS import.
"""

from __future__ import annotations

from typing import Any

import yaml

from thruster_fdd.core.errors import BadInputError

MAX_YAML_BYTES = 1 << 20
"""Largest configuration document read, bytes (the presets are about 2 KB)."""


MAX_YAML_NODES = 100_000
"""Most scalars, lists and mappings in one document."""


MAX_YAML_DEPTH = 32
"""Deepest nesting of lists and mappings."""


def _where(source: str, event: yaml.Event | yaml.Node) -> str:
    mark = event.start_mark
    return f"{source}, line {mark.line + 1}" if mark is not None else source


def _check_events(text: str, source: str) -> None:
    """Refuse anchors, aliases, explicit tags, too many nodes and too deep nesting."""
    depth = nodes = 0
    for event in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(event, yaml.AliasEvent):
            raise BadInputError(f"{_where(source, event)}: aliases (*name) are not allowed")
        if getattr(event, "anchor", None) is not None:
            raise BadInputError(f"{_where(source, event)}: anchors (&name) are not allowed")
        explicit = isinstance(event, yaml.ScalarEvent) and event.tag is not None
        explicit |= isinstance(event, yaml.CollectionStartEvent) and not event.implicit
        if explicit:
            raise BadInputError(f"{_where(source, event)}: tags ({event.tag}) are not allowed")
        if isinstance(event, yaml.ScalarEvent | yaml.CollectionStartEvent):
            nodes += 1
            if nodes > MAX_YAML_NODES:
                raise BadInputError(f"{source}: more than {MAX_YAML_NODES} values")
        if isinstance(event, yaml.CollectionStartEvent):
            depth += 1
            if depth > MAX_YAML_DEPTH:
                raise BadInputError(
                    f"{_where(source, event)}: nested deeper than {MAX_YAML_DEPTH} levels"
                )
        elif isinstance(event, yaml.CollectionEndEvent):
            depth -= 1


def _check_keys(node: yaml.Node, source: str) -> None:
    """Refuse a mapping that has the same key twice (YAML would keep the last silently)."""
    stack = [node]
    while stack:
        current = stack.pop()
        if isinstance(current, yaml.MappingNode):
            seen: set[str] = set()
            for key, value in current.value:
                if isinstance(key, yaml.ScalarNode):
                    if key.value in seen:
                        raise BadInputError(f"{_where(source, key)}: key {key.value!r} repeated")
                    seen.add(key.value)
                stack += [key, value]
        elif isinstance(current, yaml.SequenceNode):
            stack += current.value


def load_yaml(text: str, source: str) -> Any:
    """Parse one YAML document of plain data.

    Parameters
    ----------
    text : str
        The document.
    source : str
        Where it comes from (a file name), for the messages.

    Returns
    -------
    object
        Mappings, lists and scalars (None for an empty document).

    Raises
    ------
    BadInputError
        If the document is larger than ``MAX_YAML_BYTES``, is not valid YAML, holds more than
        one document, anchors, aliases, explicit tags (``!!python/object``, ``!!str``),
        more than ``MAX_YAML_NODES`` values, nesting deeper than ``MAX_YAML_DEPTH``, or a key
        twice in one mapping.
    """
    if len(text.encode("utf-8", "surrogatepass")) > MAX_YAML_BYTES:
        raise BadInputError(f"{source}: larger than {MAX_YAML_BYTES} bytes; not a configuration")
    try:
        _check_events(text, source)
        node = yaml.compose(text, Loader=yaml.SafeLoader)
        if node is None:
            return None
        _check_keys(node, source)
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        line = f", line {where.line + 1}" if where is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise BadInputError(f"{source}{line}: not valid YAML ({problem})") from None


# libyaml's emitter when PyYAML has it: the same text, five times faster (the recorder rewrites
# its bag's metadata.yaml every second: 41 ms of pure-Python YAML at 8 thrusters).
_BaseDumper: type = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


class _PlainDumper(_BaseDumper):
    """A safe dumper that writes an object seen twice in full instead of as an alias, so what
    it writes :func:`load_yaml` reads."""

    def ignore_aliases(self, data: Any) -> bool:
        return True


def dump_yaml(data: Any) -> str:
    """One YAML document of plain data, keys in insertion order, without anchors or aliases."""
    return yaml.dump(data, Dumper=_PlainDumper, sort_keys=False)
