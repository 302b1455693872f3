"""From pydantic's validation errors to one line: ``<file>: <dotted.key>: <what is wrong>``.

Every validation problem of a scenario goes through :func:`convert`, so the
messages read the same whatever component raised them: the key path as the
user wrote it (list indices included), a short reason, the value echoed
briefly, and which ``--set`` override (if any) set or touched the key.
"""

from __future__ import annotations

from typing import Any, Mapping

from pydantic import ValidationError

from dkfsim.core.errors import ScenarioError
from dkfsim.core.files import clip
from dkfsim.core.params import MAX_MAGNITUDE, MAX_SECONDS, suggest

#: Tags pydantic puts in an error location for a member of a tagged union (schedule items).
_UNION_TAGS = frozenset({"step", "ramp"})


def _loc_to_path(loc: tuple, data: Any) -> list[str]:
    """Dotted components of a pydantic ``loc``, dropping union tags."""
    parts: list[str] = []
    node = data
    for i, elem in enumerate(loc):
        last = i == len(loc) - 1
        if isinstance(node, dict) and elem in node:
            parts.append(str(elem))
            node = node[elem]
        elif isinstance(node, (list, tuple)) and isinstance(elem, int) and 0 <= elem < len(node):
            parts.append(str(elem))
            node = node[elem]
        elif (node is None or isinstance(node, dict)) and not last and elem in _UNION_TAGS:
            continue  # a union member's tag (e.g. 'uniform_steps'), not a key
        elif isinstance(elem, str) and (elem.startswith(("function-", "literal[", "int", "str"))
                                        and not last):
            continue
        else:
            parts.append(str(elem))
            node = None
    return parts


#: Fields whose allowed words are a fixed list (components' names come from their registries).
_LITERAL_FIELDS = {"weights": ("weights", ("unit", "paper")),
                   "fusion": ("fusion", ("matrix", "diagonal", "none")),
                   "kind": ("model kind", ("constant_acceleration", "constant_velocity", "linear"))}

#: ... and those whose meaning depends on the key above them.
_LITERAL_PATHS: dict[tuple[str, ...], tuple[str, tuple[str, ...]]] = {("access", "kind"): ("access kind", ("csma",))}

_BOUND_WORDS = {"greater_than_equal": (">=", "ge"), "greater_than": (">", "gt"),
                "less_than_equal": ("<=", "le"), "less_than": ("<", "lt")}


def _reason(err: Mapping[str, Any], path: list[str]) -> tuple[str, list[str]]:
    """Short message for one pydantic error, and the (maybe extended) path."""
    etype = err["type"]
    ctx = err.get("ctx") or {}
    inp = err.get("input")
    field = path[-1] if path else ""
    if etype in ("dkfsim", "unknown_key"):
        return str(ctx.get("reason", err["msg"])), path
    if etype == "missing":
        return "required key is missing", path
    if etype == "extra_forbidden":
        return "unknown key", path
    if etype == "literal_error" and field in _LITERAL_FIELDS:
        what, valid = _LITERAL_PATHS.get(tuple(path[-2:]), _LITERAL_FIELDS[field])
        return (f"unknown {what} {clip(inp)}{suggest(inp, valid)}; valid: " + ", ".join(valid)), path
    if etype in _BOUND_WORDS:
        word, k = _BOUND_WORDS[etype]
        bound = ctx.get(k)
        why = {MAX_SECONDS: f"{MAX_SECONDS:.10g} s = 2^62 ns, the span of the int64 nanosecond clock",
               MAX_MAGNITUDE: f"{MAX_MAGNITUDE:g}, so that products stay within float64"}
        if bound in why:
            return f"must be {word} {why[bound]}; got {clip(inp)}", path
        return f"must be {word} {bound}, got {clip(inp)}", path
    if etype in ("model_type", "model_attributes_type", "dict_type"):
        return f"must be a mapping, got {type(inp).__name__} {clip(inp)}", path
    if etype in ("int_type", "int_from_float", "int_parsing"):
        return f"must be an integer, got {clip(inp)}", path
    if etype in ("float_type", "float_parsing"):
        return f"must be a number, got {clip(inp)}", path
    if etype == "bool_type":
        return f"must be true or false, got {clip(inp)}", path
    if etype in ("tuple_type", "list_type"):
        return f"must be a list, got {type(inp).__name__} {clip(inp)}", path
    if etype in ("string_type",):
        return f"must be a string, got {clip(inp)}", path
    if etype == "string_too_long":
        return f"must be at most {ctx.get('max_length')} characters long, got {clip(inp)}", path
    if etype == "finite_number":
        return f"must be a finite number, got {clip(inp)}", path
    if etype in ("too_short", "too_long") and field == "sensors":
        return "at least one sensor is required", path
    msg = " ".join(str(err["msg"]).split())
    if inp is not None and not isinstance(inp, (dict, list, tuple)):
        msg += f" (got {clip(inp)})"
    return msg, path


def convert(exc: ValidationError, data: Any, source: str,
             override_keys: Mapping[str, str], max_items: int | None = None) -> ScenarioError:
    """One message for every problem ``exc`` lists (the first ``max_items`` of them, and how
    many more, when given: a tampered table can have a problem per row).  ``override_keys`` maps
    each ``--set`` key to its text, in the order they were applied (a key set twice where it was
    set last)."""
    items = []
    errors = exc.errors()
    more = len(errors) - max_items if max_items is not None and len(errors) > max_items else 0
    for err in errors[:len(errors) - more]:
        loc = tuple(err["loc"])
        extra = (err.get("ctx") or {}).get("key") if err["type"] in ("dkfsim", "unknown_key") \
            else None
        if extra:  # the model pointed at one of its own keys: walk it with the rest
            loc = loc + tuple(str(extra).split("."))
        path = _loc_to_path(loc, data)
        reason, path = _reason(err, path)
        dotted = ".".join(path)
        # The value was set by the last override applied at the key or above it (a later
        # 'medium.access={...}' replaces an earlier 'medium.access.cw=...'; a later
        # 'medium.access.cw=...' changes only cw of an earlier 'medium.access={...}').
        setters = [text for key, text in override_keys.items() if dotted == key or dotted.startswith(key + ".")]
        if setters:
            reason += f" (set by override {clip(setters[-1])})"
        else:
            for key, text in override_keys.items():
                if dotted and key.startswith(dotted + "."):
                    reason += f" (after override {clip(text)})"
                    break
        items.append((dotted, reason))
    first_path, first_reason = items[0]
    message = first_reason
    for dotted, reason in items[1:]:
        message += f"; {dotted}: {reason}" if dotted else f"; {reason}"
    if more:
        message += f"; and {more} more problem{'s' * (more > 1)} of the same kind or others"
    return ScenarioError(message, source=source, path=first_path or None)


