"""Plain-text tables for a terminal: columns aligned, a rule under the header."""

from __future__ import annotations


def aligned(rows: list[tuple[str, ...]], left=(0,)) -> list[str]:
    """Rows of cells as text lines: the columns in ``left`` left-aligned, the others
    right-aligned; a rule under the header row."""
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    left = {c % len(widths) for c in left}
    fmt = lambda r: "  " + "  ".join(c.ljust(w) if j in left else c.rjust(w)  # noqa: E731
                                     for j, (c, w) in enumerate(zip(r, widths))).rstrip()
    return [fmt(rows[0]), "  " + "  ".join("-" * w for w in widths)] + [fmt(r) for r in rows[1:]]
