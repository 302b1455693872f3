"""What a scenario key means to a reader: its name in words and its unit, for axis labels.

A sweep's grid key (``links.default.latency.d_t``) is exact but not readable on an axis; the
figures label it ``per-hop delay bound d_t [ticks]`` (docs/decisions.md, 198).  The table is
keyed by the last parts of the dotted key, longest match first, so a key of a link override
or of any latency model reads the same; units are those of docs/scenarios.md (times in
seconds, ``d_t`` and lengths in ticks, rates in bit/s).  A key it does not know keeps its
dotted name, without a unit.
"""

from __future__ import annotations

#: Last parts of a dotted scenario key -> (what it is, unit; "" for none).
KEY_LABELS: dict[str, tuple[str, str]] = {
    "latency.d_t": ("per-hop delay bound d_t", "ticks"),
    "links.d_t": ("delay bound d_t the buffer is sized for", "ticks"),
    "d_t": ("delay bound d_t", "ticks"),
    "steps": ("run length", "ticks"),
    "buffer_length": ("buffer length L", "ticks"),
    "model.T": ("sampling period T", "s"),
    "latency.value": ("link latency", "s"),
    "latency.mean": ("mean link latency", "s"),
    "latency.median": ("median link latency", "s"),
    "latency.offset": ("latency offset", "s"),
    "latency.low": ("least link latency", "s"),
    "latency.high": ("largest link latency", "s"),
    "medium.rate": ("channel rate", "bit/s"),
    "rate": ("link rate", "bit/s"),
    "queue.packets": ("queue limit", "packets"),
    "queue.bytes": ("queue limit", "bytes"),
    "background.packets_per_second": ("background load", "packets/s"),
    "background.size": ("background packet size", "bytes"),
    "loss": ("packet loss probability", ""),
    "duplicate": ("duplication probability", ""),
    "rounds": ("consensus rounds", "per tick"),
    "omega": ("hcmci weight omega", ""),
    "protocol": ("exchange protocol", ""),
    "fusion": ("fusion", ""),
    "seed": ("seed", ""),
}


def key_label(key: str) -> tuple[str, str]:
    """``(words, unit)`` of a dotted scenario key (or a sweep's ``param:NAME``); the key itself
    and no unit when the table does not know it."""
    name = str(key).removeprefix("param:")
    parts = name.split(".")
    for n in range(min(len(parts), 2), 0, -1):
        known = KEY_LABELS.get(".".join(parts[-n:]))
        if known is not None:
            return known
    return name, ""
