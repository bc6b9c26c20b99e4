"""The one YAML reader: safe (no tags that build Python objects) and bounded before anything is built.

``yaml.safe_load`` builds no Python objects from tags, but it still expands
whatever a small file asks for: nine levels of nine aliases are 9^9 list
items that anything walking the result (``np.asarray``, a ``repr``, a merge
key ``<<``) has to visit; an anchor used inside itself makes a list that
contains itself; and ten thousand nested brackets exhaust the recursion
limit.  :class:`BoundedLoader` checks the composed document (the node graph,
before any Python value exists):

* nesting at most :data:`MAX_DEPTH` levels;
* at most :data:`MAX_NODES` nodes once every alias is expanded (counted on
  the graph with shared nodes counted once per use, so the check itself costs
  the document's size, not its expansion);
* no alias inside its own anchor (a recursive structure).

Every failure of :func:`parse_yaml` / :func:`read_yaml` is one
:class:`~nnsf.errors.InputError` naming the file, the line or key path, and
what was expected.  This module needs only PyYAML and :mod:`nnsf.errors`, so
checking ``params.yaml`` stays light; :mod:`nnsf.io` re-exports it.
"""
from __future__ import annotations

from pathlib import Path

import yaml
from yaml.nodes import MappingNode, Node, SequenceNode

from nnsf.errors import InputError, exception_line, read_text

#: Deepest nesting of lists and mappings accepted (configuration files use fewer than ten).
MAX_DEPTH = 64
#: Most nodes (scalars, lists, mappings) once aliases are expanded.
MAX_NODES = 200_000
#: Largest YAML file read (bytes): configuration files are a few KB.
MAX_YAML_BYTES = 10_000_000


class _Refused(yaml.YAMLError):
    """A bound of :class:`BoundedLoader` was hit; ``where`` names the key path or line."""

    def __init__(self, where: str, expected: str, got: str | None = None):
        super().__init__(expected)
        self.where, self.expected, self.got = where, expected, got


def _line(node: Node) -> str:
    return f"line {node.start_mark.line + 1}" if node.start_mark is not None else "file"


class BoundedLoader(yaml.SafeLoader):
    """:class:`yaml.SafeLoader` that refuses deep, recursive or alias-inflated documents (module docstring)."""

    max_depth = MAX_DEPTH
    max_nodes = MAX_NODES

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        self._depth += 1
        try:
            if self._depth > self.max_depth:
                raise _Refused(f"line {self.peek_event().start_mark.line + 1}",
                               f"YAML nested at most {self.max_depth} levels deep")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_object(self, node, deep=False):
        # A scalar a constructor cannot convert (an integer of 5000 digits, a date of month 13)
        # raises a plain Python error: named here with its line.
        try:
            return super().construct_object(node, deep)
        except (ValueError, TypeError, AttributeError, OverflowError) as exc:
            raise _Refused(_line(node), "valid YAML values", exception_line(exc)) from None

    def compose_document(self):
        node = super().compose_document()
        if node is not None:
            _check_expansion(node, self.max_nodes)
        return node


def _children(node: Node) -> list[Node]:
    if isinstance(node, SequenceNode):
        return list(node.value)
    if isinstance(node, MappingNode):
        return [n for kv in node.value for n in kv]
    return []


def _check_expansion(root: Node, limit: int) -> None:
    """Refuse a node graph with a cycle, or more than ``limit`` nodes once aliases are expanded.

    Sizes are computed once per node (iteratively: no recursion limit) and
    summed over every use, so an alias bomb is measured without expanding it.
    """
    size: dict[int, int] = {}
    state: dict[int, int] = {}          # 1: on the current path, 2: done
    stack = [(root, False)]
    while stack:
        node, leaving = stack.pop()
        key = id(node)
        if leaving:
            size[key] = min(1 + sum(size[id(c)] for c in _children(node)), limit + 1)
            state[key] = 2
            continue
        if state.get(key) == 2:
            continue
        if state.get(key) == 1:
            raise _Refused(_line(node), "YAML without an alias inside its own anchor (a structure "
                           "that contains itself)")
        state[key] = 1
        stack.append((node, True))
        for child in _children(node):
            if state.get(id(child)) == 1:
                raise _Refused(_line(child), "YAML without an alias inside its own anchor (a structure "
                               "that contains itself)")
            if state.get(id(child)) != 2:
                stack.append((child, False))
    if size[id(root)] > limit:
        raise _Refused(_where(root, size, limit), f"YAML of at most {limit} values once its aliases "
                       "are expanded", f"more than {limit} values")


def _where(root: Node, size: dict[int, int], limit: int) -> str:
    """The key path (``a.b[3].c``) of the innermost mapping value that alone exceeds ``limit``."""
    path, node = "", root
    while True:
        if isinstance(node, MappingNode):
            big = [(k, v) for k, v in node.value if size.get(id(v), 0) > limit]
            if not big:
                return path or _line(node)
            k, node = big[0]
            name = str(k.value) if not isinstance(k.value, list) else "?"
            path = f"{path}.{name}" if path else name
        elif isinstance(node, SequenceNode):
            big = [(i, v) for i, v in enumerate(node.value) if size.get(id(v), 0) > limit]
            if not big or not isinstance(big[0][1], MappingNode):
                return path or _line(node)
            i, node = big[0]
            path = f"{path}[{i}]"
        else:
            return path or _line(node)


def parse_yaml(text: str, source, what: str = "YAML"):
    """The value of a YAML document ``text`` read from ``source`` (:class:`BoundedLoader`).

    Raises :class:`InputError` naming ``source`` and the line or key path:
    invalid YAML, a tag that would build a Python object, several documents,
    or a bound of :class:`BoundedLoader` exceeded.
    """
    loader = BoundedLoader(text)
    try:
        return loader.get_single_data()
    except _Refused as exc:
        raise InputError(source, exc.where, exc.expected, reason=exc.got) from None
    except yaml.constructor.ConstructorError as exc:
        mark = exc.problem_mark
        tag = "could not determine a constructor" in (exc.problem or "")
        raise InputError(source, f"line {mark.line + 1}" if mark else "file",
                         f"{what} without tags that build Python objects" if tag else f"valid {what} values",
                         reason=exc.problem) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise InputError(source, f"line {mark.line + 1}" if mark else "file", f"valid {what}",
                         reason=getattr(exc, "problem", None) or str(exc)) from None
    except RecursionError:  # a bound above Python's recursion limit: never with MAX_DEPTH
        raise InputError(source, "file", f"{what} nested at most {MAX_DEPTH} levels deep") from None
    finally:
        loader.dispose()


def read_yaml(path, max_bytes: int = MAX_YAML_BYTES, what: str = "a YAML file"):
    """The value of the YAML file ``path``: :func:`nnsf.errors.read_text` then :func:`parse_yaml`."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file", f"an existing {what}")
    return parse_yaml(read_text(path, max_bytes, what), path, what="YAML")
