"""One YAML reading for scenario files, sweep files and ``--set`` values.

* safe tags only (no Python objects), ``1e-3`` read as a float (YAML 1.1
  would read a string), duplicate keys rejected -- except keys brought in by
  a merge key (``<<: *base``), which the mapping's own keys override;
* hostile input ends in a clear error, quickly: nesting deeper than
  :data:`~dkfsim.core.files.MAX_DEPTH` levels, an alias that refers to
  itself, and alias expansion beyond :data:`~dkfsim.core.files.MAX_NODES`
  nodes ("billion laughs") are refused in one pass over the parser's events,
  before anything is built from them (libyaml parses when it is installed,
  as it is with PyYAML's wheels).
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Any

import yaml

from dkfsim.core.files import MAX_DEPTH, MAX_NODES, clip


class _TooBig(yaml.YAMLError):
    """The document is too deep, refers to itself or expands too far."""

    def __init__(self, problem: str, mark):
        super().__init__(problem)
        self.problem = problem
        self.problem_mark = mark


#: Longest plain number read: Python refuses to convert integers of more than 4300 digits (a
#: ValueError deep in the loader), and no setting needs more than a few dozen characters.
MAX_NUMBER_CHARS = 1000
_NUMBER = re.compile(r"[-+]?[0-9_.,:eExXoObBa-fA-F]+")


def _check_events(text: str, base) -> None:
    """Walk the YAML events once, refusing deep nesting and large alias expansion.

    Sizes are counted per node: a scalar or alias target counts in full, so
    an alias to a big anchored list costs what it expands to.  An alias to a
    node that is still open refers to itself (a recursive structure).
    """
    try:
        _walk_events(yaml.parse(text, Loader=base))
    except yaml.YAMLError as err:
        # libyaml's scanner has its own depth limit (1000 flow levels), which it may meet
        # before it hands over the first event (a flow collection's key is looked for ahead):
        # the same refusal as ours, in our words
        if "maximum nesting depth" in str(getattr(err, "problem", "")):
            raise _TooBig(f"nested deeper than {MAX_DEPTH} levels", getattr(err, "problem_mark", None)) from None
        raise


def _walk_events(events) -> None:
    """:func:`_check_events` on the parser's ``events``."""
    stack: list[list] = [[0, None]]              # [nodes so far, anchor] per open collection
    sizes: dict[str, int] = {}
    total = 0
    for ev in events:
        if isinstance(ev, (yaml.SequenceStartEvent, yaml.MappingStartEvent)):
            if len(stack) > MAX_DEPTH:
                raise _TooBig(f"nested deeper than {MAX_DEPTH} levels", ev.start_mark)
            stack.append([0, ev.anchor])
            continue
        if isinstance(ev, (yaml.SequenceEndEvent, yaml.MappingEndEvent)):
            size, anchor = stack.pop()
            size += 1
        elif isinstance(ev, yaml.ScalarEvent):
            if ev.implicit[0] and len(ev.value) > MAX_NUMBER_CHARS and _NUMBER.fullmatch(ev.value):
                raise _TooBig(f"a number written with {len(ev.value):,} characters (at most "
                              f"{MAX_NUMBER_CHARS:,} are read)", ev.start_mark)
            size, anchor = 1, ev.anchor
        elif isinstance(ev, yaml.AliasEvent):
            if ev.anchor not in sizes:
                if any(a == ev.anchor for _, a in stack):
                    raise _TooBig(f"alias *{ev.anchor} refers to a node that contains it "
                                  "(a recursive structure)", ev.start_mark)
                continue                         # undefined: the loader reports it
            size, anchor = sizes[ev.anchor], None
        else:
            continue
        if anchor is not None:
            sizes[anchor] = size
        stack[-1][0] += size
        total += size if isinstance(ev, yaml.AliasEvent) else 1
        if total > MAX_NODES or stack[-1][0] > MAX_NODES:
            raise _TooBig(f"the document expands to more than {MAX_NODES:,} nodes (aliases "
                          "counted in full); refusing an alias bomb", ev.start_mark)


#: libyaml's safe loader when installed, else PyYAML's (to a type checker: PyYAML's, whose
#: constructor and resolver libyaml's shares).
if TYPE_CHECKING:
    _Base = yaml.SafeLoader
else:
    _Base = yaml.CSafeLoader if getattr(yaml, "__with_libyaml__", False) else yaml.SafeLoader


class SafeLoader(_Base):
    """PyYAML's safe loader (libyaml's when installed) with the readings of the module
    docstring; :func:`parse_yaml` checks the limits before it composes anything."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue              # merged keys may be overridden: not duplicates
                key = self.construct_object(key_node, deep=deep)
                try:
                    if key in seen:
                        raise yaml.constructor.ConstructorError(
                            "while constructing a mapping", node.start_mark,
                            f"duplicate key {clip(key, 40)} (first at line {seen[key].line + 1})",
                            key_node.start_mark)
                    seen[key] = key_node.start_mark
                except TypeError:        # unhashable key: the base class complains
                    pass
        return super().construct_mapping(node, deep=deep)


SafeLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"))


def yaml_error_text(err: yaml.YAMLError) -> str:
    """One line saying what is wrong with a YAML text and where."""
    mark = getattr(err, "problem_mark", None) or getattr(err, "context_mark", None)
    problem = getattr(err, "problem", None) or str(err).splitlines()[0]
    context = getattr(err, "context", None)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
    kind = "YAML input refused" if isinstance(err, _TooBig) else "YAML syntax error"
    text = f"{kind}{where}: {problem}"
    cmark = getattr(err, "context_mark", None)
    if context and context not in problem:
        if cmark is not None and mark is not None and cmark.line != mark.line:
            context += f" started at line {cmark.line + 1}"
        text += f" ({context})"
    return " ".join(text.split())


def parse_yaml(text: str) -> Any:
    """The data of a YAML text; raises ``yaml.YAMLError`` (see :func:`yaml_error_text`)."""
    _check_events(text, _Base)
    try:
        return yaml.load(text, Loader=SafeLoader)
    except RecursionError:               # pragma: no cover - MAX_DEPTH keeps us far from it
        raise _TooBig(f"nested deeper than {MAX_DEPTH} levels", None) from None
