"""Origin sets as bitmasks: Python ints on the wire, 64-bit words in arrays.

A packet of the exchange protocols names the origins of a row's aggregate
by a non-negative int (bit ``o`` for origin ``o``, any width).  Work on many
of them at once goes through little-endian 64-bit words: one
``to_bytes``/``frombuffer`` for the lot, then set bits found in numpy (the
pure path) or by a compiled kernel walking the words.
"""

from __future__ import annotations

import numpy as np


def mask_words(masks, n_words: int) -> np.ndarray:
    """``masks`` (ints) as a ``(len(masks), n_words)`` array of little-endian uint64 words
    (writable: a kernel given it compiles for the same type as for its other callers)."""
    nb = 8 * n_words
    raw = bytearray(b"".join(m.to_bytes(nb, "little") for m in masks))
    return np.frombuffer(raw, dtype=np.uint64).reshape(len(masks), n_words)


def set_bits(words: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The set bits of each row of ``words``: ``(k, o)`` with bit ``o`` set in row ``k``,
    rows ascending and bits ascending within a row."""
    raw = np.ascontiguousarray(words).view(np.uint8)
    nb = raw.shape[1]
    raw = raw.reshape(-1)
    # Only the non-zero bytes are unpacked: wide masks are mostly zeros.
    nz = np.flatnonzero(raw)
    kb, bit = np.nonzero(np.unpackbits(raw[nz][:, None], axis=1, bitorder="little"))
    k, o = np.divmod(nz[kb], nb)
    return k.astype(np.intp), (o * 8 + bit).astype(np.intp)
