"""Reading ``.npz`` files someone else may have written: headers first, never a pickle.

A result folder (``run.npz``, ``curves.npz``) may come from anyone: a paper's
supplement, a colleague, a download.  :func:`read_npz` reads one without trusting
it (docs/security.md):

* an array of Python objects (dtype ``object``, or a structured dtype holding
  one) is refused: loading it would unpickle, and unpickling runs code;
* every member's header (shape, dtype) is read *before* its data, and the
  arrays asked for must fit :func:`budget` (a share of the available memory)
  and be backed by the bytes the file holds -- a small compressed file that
  claims gigabytes (a "zip bomb"; dkfsim writes npz files uncompressed) is
  refused without being inflated;
* a truncated, empty or corrupt file, a bad CRC or a malformed header is a
  :class:`~dkfsim.core.errors.DkfsimError` naming the file and the array.
"""

from __future__ import annotations

import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Self

import numpy as np

from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import clip, open_regular
from dkfsim.core.resources import MEMORY_FRACTION, available_memory, human_bytes

#: Largest npz file opened (bytes): a result folder's arrays, uncompressed.
MAX_NPZ_BYTES = 1 << 40
#: Most members an npz file may have (dkfsim writes a few dozen).
MAX_MEMBERS = 10_000
#: Longest ``.npy`` header read (numpy's own default bound).
MAX_HEADER = 10_000
#: A compressed member may claim at most this many times its stored bytes, beyond
#: :data:`SMALL_BYTES` (deflate reaches ~1000x on zeros; real floats compress ~1-3x).
MAX_RATIO = 64
SMALL_BYTES = 64 << 20
#: Share of the memory budget the arrays read at once may take (callers compute with them).
READ_SHARE = 0.25
#: What reading a damaged zip member raises: a bad header or CRC, a corrupt deflate stream,
#: an unsupported or encrypted member, a short read.
_ZIP_ERRORS = (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error, NotImplementedError,
               RuntimeError, OverflowError, KeyError, TypeError, SyntaxError, RecursionError, MemoryError)


@dataclass(frozen=True)
class ArrayHeader:
    """What a member's ``.npy`` header says, read without its data."""

    name: str
    shape: tuple[int, ...]
    dtype: np.dtype
    fortran: bool
    nbytes: int           # bytes its data claims
    stored: int           # bytes of the member in the zip (compressed or not)
    compressed: bool

    @property
    def numeric(self) -> bool:
        """bool, integer or floating point (what the figures and metrics compute with)."""
        return self.dtype.kind in "biuf"


def budget() -> int:
    """Bytes of arrays a reader may load at once: :data:`READ_SHARE` of the memory a command
    may plan to use (``MEMORY_FRACTION`` of the available memory)."""
    return int(available_memory() * MEMORY_FRACTION * READ_SHARE)


def _bad(path, what: str) -> DkfsimError:
    return DkfsimError(f"{path}: {what}")


def _header(z: zipfile.ZipFile, info: zipfile.ZipInfo, path) -> ArrayHeader:
    name = info.filename.removesuffix(".npy")
    try:
        with z.open(info) as fh:
            version = np.lib.format.read_magic(fh)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(fh, max_header_size=MAX_HEADER)
            elif version in ((2, 0), (3, 0)):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(fh, max_header_size=MAX_HEADER)
            else:
                raise ValueError(f"unknown .npy format version {version}")
            offset = fh.tell()
    except _ZIP_ERRORS as exc:
        raise _bad(path, f"array {clip(name)}: not a valid .npy header ({clip(str(exc), 120)})") from None
    if dtype.hasobject:
        raise _bad(path, f"array {clip(name)} holds Python objects (dtype {dtype}); dkfsim never "
                         "reads those, as loading them would run code (unpickling): it is not a "
                         "file dkfsim wrote")
    if any(not isinstance(d, int) or d < 0 for d in shape):
        raise _bad(path, f"array {clip(name)}: invalid shape {clip(shape)}")
    count = 1
    for d in shape:
        count *= d
    nbytes = count * dtype.itemsize
    compressed = info.compress_type != zipfile.ZIP_STORED
    if nbytes > info.file_size - offset:
        raise _bad(path, f"array {clip(name)}: its header claims {human_bytes(nbytes)} but the file "
                         f"holds {human_bytes(max(0, info.file_size - offset))} (truncated or tampered)")
    return ArrayHeader(name, tuple(shape), dtype, bool(fortran), nbytes, info.compress_size, compressed)


class NpzFile:
    """An npz file opened for reading: its headers now, the arrays asked for later.

    ``with NpzFile(path) as z: z.headers["truth"].shape; z.read(["truth", "t"])``.
    """

    def __init__(self, path, what: str = "npz file"):
        self.path = Path(path)
        fh = open_regular(self.path, limit=MAX_NPZ_BYTES, what=what)
        try:
            self._zip = zipfile.ZipFile(fh)
        except _ZIP_ERRORS as exc:
            fh.close()
            raise _bad(self.path, f"not a readable .npz file ({clip(str(exc), 120)})") from None
        self._file = fh
        try:
            infos = self._zip.infolist()
            if len(infos) > MAX_MEMBERS:
                raise _bad(self.path, f"{len(infos):,} members, more than the {MAX_MEMBERS:,} an npz "
                                      "file of dkfsim has")
            self.headers: dict[str, ArrayHeader] = {}
            self._infos: dict[str, zipfile.ZipInfo] = {}
            for info in infos:
                if info.is_dir():
                    continue
                h = _header(self._zip, info, self.path)
                self.headers[h.name] = h
                self._infos[h.name] = info
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._zip.close()
        self._file.close()          # (a ZipFile given an open file leaves it open)

    def __contains__(self, key: object) -> bool:
        return key in self.headers

    @property
    def files(self) -> list[str]:
        return list(self.headers)

    def check_size(self, keys) -> None:
        """Refuse (before reading) arrays that would not fit the memory budget, or compressed
        members that claim far more than their stored bytes."""
        total = 0
        for key in keys:
            h = self.headers[key]
            if h.compressed and h.nbytes > SMALL_BYTES and h.nbytes > MAX_RATIO * max(h.stored, 1):
                raise _bad(self.path, f"array {clip(key)} claims {human_bytes(h.nbytes)} inflated from "
                                      f"{human_bytes(h.stored)} compressed (a zip bomb? dkfsim writes "
                                      "npz files uncompressed); refused without reading it")
            total += h.nbytes
        limit = budget()
        if total > limit:
            raise _bad(self.path, f"its arrays need {human_bytes(total)} in memory, more than the "
                                  f"{human_bytes(limit)} a reader may use here; refused without reading them")

    def read(self, keys=None) -> dict[str, np.ndarray]:
        """The arrays ``keys`` (default: all), after :meth:`check_size`."""
        keys = list(self.headers) if keys is None else list(keys)
        for key in keys:
            if key not in self.headers:
                raise _bad(self.path, f"no array {clip(key)}")
        self.check_size(keys)
        out = {}
        for key in keys:
            info = self._infos[key]
            try:
                with self._zip.open(info) as fh:
                    a = np.lib.format.read_array(fh, allow_pickle=False, max_header_size=MAX_HEADER)
            except _ZIP_ERRORS as exc:
                raise _bad(self.path, f"array {clip(key)}: cannot read it ({clip(str(exc), 120)})") from None
            out[key] = a
        return out


def read_npz(path, keys=None, what: str = "npz file") -> dict[str, np.ndarray]:
    """The arrays ``keys`` (default: all) of the npz file ``path``, read safely (module docstring)."""
    with NpzFile(path, what) as z:
        return z.read(keys)
