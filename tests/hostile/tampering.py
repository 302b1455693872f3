"""Ways to tamper with a legitimate result folder or sweep database, for the hostile tests (the
fuzzer, tools/fuzz_results.py, has its own vocabulary).  Each function edits a copy in place."""

from __future__ import annotations

import json
import sqlite3
import zipfile
from pathlib import Path

import numpy as np


# =========================================================================== npz files
def npz_arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def npz_replace(path: Path, **arrays) -> None:
    """Rewrite ``path`` with some arrays replaced (``None`` removes one)."""
    data = npz_arrays(path)
    for k, v in arrays.items():
        if v is None:
            data.pop(k, None)
        else:
            data[k] = v
    np.savez(path, **data)


def npz_claiming(path: Path, claims: dict[str, tuple]) -> int:
    """Write ``path`` as an npz whose members ``claims`` (name -> shape) hold float64 zeros of
    that shape, deflated as they are streamed (a gigabyte of zeros becomes a megabyte): the
    "3 MB file holding 60 M rows" of issue 20.  Returns the file's size."""
    chunk = bytes(16 << 20)
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=9) as z:
        for name, shape in claims.items():
            header = {"descr": "<f8", "fortran_order": False, "shape": tuple(shape)}
            buf = _npy_header(header)
            total = 8 * int(np.prod(shape))
            with z.open(name + ".npy", "w", force_zip64=True) as fh:
                fh.write(buf)
                left = total
                while left > 0:
                    n = min(left, len(chunk))
                    fh.write(chunk[:n])
                    left -= n
    return path.stat().st_size


def _npy_header(d: dict) -> bytes:
    text = repr(d).encode("latin1")
    pad = 64 - (10 + len(text) + 1) % 64
    text += b" " * pad + b"\n"
    return b"\x93NUMPY\x01\x00" + len(text).to_bytes(2, "little") + text


def truncate(path: Path, fraction: float = 0.5) -> None:
    data = path.read_bytes()
    path.write_bytes(data[:int(len(data) * fraction)])


def flip_npz_member_byte(path: Path, member: str) -> None:
    """Flip a byte inside the data of one stored member (its CRC no longer matches)."""
    with zipfile.ZipFile(path) as z:
        info = z.getinfo(member + ".npy")
    data = bytearray(path.read_bytes())
    # local header: 30 bytes + name + extra; the data follows
    off = info.header_offset
    n, m = int.from_bytes(data[off + 26:off + 28], "little"), int.from_bytes(data[off + 28:off + 30], "little")
    start = off + 30 + n + m
    data[start + info.compress_size - 1] ^= 0xFF
    path.write_bytes(bytes(data))


# =========================================================================== JSON files
def edit_json(path: Path, edit) -> None:
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))


def deep(depth: int = 1000):
    value = 1
    for _ in range(depth):
        value = [value]
    return value


def deep_json_text(depth: int = 1000) -> str:
    return "[" * depth + "]" * depth


# =========================================================================== sweep databases
def sql(db: Path, *statements, params=()) -> None:
    with sqlite3.connect(db) as conn:
        for s in statements:
            conn.execute(s, params)
    conn.close()


def set_values_json(db: Path, edit) -> None:
    with sqlite3.connect(db) as conn:
        for h, text in conn.execute("SELECT param_hash, values_json FROM params").fetchall():
            conn.execute("UPDATE params SET values_json=? WHERE param_hash=?", (json.dumps(edit(json.loads(text))), h))
    conn.close()
