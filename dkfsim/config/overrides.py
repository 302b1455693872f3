"""``--set dotted.key=value``: overrides applied to a scenario's raw mapping.

The value is parsed as YAML (``--set sensors.0.R=[[2.0]]``); list indices
work; a missing mapping on the way is created.  A number names a mapping's integer key
(YAML reads ``0:`` as one) as well as its string key ``'0'``.  Every problem is a
:class:`~dkfsim.core.errors.ScenarioError` naming the override.
"""

from __future__ import annotations

import re
from typing import Any

import yaml

from dkfsim.config.yaml import parse_yaml, yaml_error_text
from dkfsim.core.errors import ScenarioError
from dkfsim.core.files import clip

_INDEX = re.compile(r"^-?\d+$")


def _key_of(node: dict, part: str) -> Any:
    """The key of ``node`` that the override's ``part`` names: ``part`` itself, or the integer
    key a YAML ``0:`` reads as (``mobility.vehicles.0.vehicle`` changes the vehicle the file
    writes as ``0:``, rather than adding a key ``'0'`` beside it)."""
    if part not in node and _INDEX.match(part):
        number = int(part)
        for k in node:
            if isinstance(k, int) and not isinstance(k, bool) and k == number:
                return k
    return part


def apply_override(data: dict, text: str, source: str) -> str:
    """Apply one ``dotted.key=value`` to ``data`` in place; return the key."""
    if not isinstance(text, str) or "=" not in text:
        raise ScenarioError(f"bad override {clip(text)}: expected dotted.key=value "
                            "(e.g. links.default.latency.d_t=0)", source=source)
    key, _, raw = text.partition("=")
    key = key.strip()
    parts = key.split(".")
    if not key or any(p == "" for p in parts):
        raise ScenarioError(f"bad override {clip(text)}: empty key component", source=source)
    try:
        value = parse_yaml(raw) if raw.strip() else None
    except yaml.YAMLError as err:
        raise ScenarioError(f"bad override value {clip(raw)}: {yaml_error_text(err)}",
                            source=source, path=key) from None
    node: Any = data
    for depth, part in enumerate(parts):
        here = ".".join(parts[:depth + 1])
        last = depth == len(parts) - 1
        if isinstance(node, list):
            if not _INDEX.match(part):
                raise ScenarioError(f"override {clip(text)}: {parts[depth - 1] if depth else key} "
                                    f"is a list; {part!r} is not an index", source=source,
                                    path=here)
            idx = int(part)
            if not 0 <= idx < len(node):
                raise ScenarioError(f"override {clip(text)}: list index {idx} out of range "
                                    f"(the list has {len(node)} entries)", source=source,
                                    path=here)
            if last:
                node[idx] = value
            else:
                if node[idx] is None:
                    node[idx] = {}
                node = node[idx]
        elif isinstance(node, dict):
            part = _key_of(node, part)
            if last:
                node[part] = value
            else:
                if node.get(part) is None:
                    node[part] = {}
                node = node[part]
        else:
            parent = ".".join(parts[:depth])
            raise ScenarioError(f"override {clip(text)}: {parent} is a scalar "
                                f"({clip(node)}); cannot set {part!r} inside it",
                                source=source, path=here)
    return key
