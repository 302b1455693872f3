"""Reading what a user hands us, safely, and echoing it back briefly.

:func:`open_regular` is how every file dkfsim reads is opened: it refuses what is not a
regular file (a directory, a FIFO, a socket, a device such as ``/dev/zero`` behind a symlink)
and files larger than a stated limit *before* reading them, checking the descriptor it opened
(so a FIFO cannot block the open, and the file checked is the file read); :func:`read_text`
reads such a file as UTF-8, :func:`check_regular_file` checks one a library opens itself
(SQLite, pyarrow).  :func:`check_plain_data` bounds the nesting and size of data handed to the
Python API; :func:`clip` shortens any value echoed in an error message and :func:`shown` a
path; :func:`printable` is the one escaper of everything a terminal, a warning or a figure
shows.  The limits (:data:`MAX_DEPTH`, :data:`MAX_NODES`) are the YAML loader's too
(:mod:`dkfsim.config.yaml`).
"""

from __future__ import annotations

import json
import os
import re
import stat
from collections.abc import Iterable
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from dkfsim.core.encoding import from_json
from dkfsim.core.errors import DkfsimError

#: Deepest nesting of lists and mappings a file may have.
MAX_DEPTH = 64
#: Largest number of YAML nodes a document may expand to, aliases counted in full.
MAX_NODES = 2_000_000
#: Largest scenario or sweep file read (bytes).
MAX_YAML_BYTES = 8 << 20
#: Largest data file (latency trace, track) read (bytes).
MAX_DATA_BYTES = 64 << 20
#: Largest JSON file of a result folder read (bytes).
MAX_JSON_BYTES = 64 << 20
#: Deepest nesting of a result's JSON file: a scenario's, within the result's own keys.
MAX_JSON_DEPTH = MAX_DEPTH + 8


def shown(path: Any, limit: int = 160) -> str:
    """A path as a message names it: at most ``limit`` characters, the middle cut out of a
    longer one (a 5000-character name stays one readable line)."""
    text = os.fspath(path) if isinstance(path, (str, os.PathLike)) else str(path)
    if len(text) <= limit:
        return text
    half = (limit - 3) // 2
    return f"{text[:half]}...{text[-half:]}"


def clip(value: Any, limit: int = 80) -> str:
    """``repr(value)`` cut to ``limit`` characters, for error messages (an integer of more than
    24 digits in short, ``1.00e+300``: its leading digits and its size, not a cut-off run)."""
    try:
        text = _short_int(value) if _is_long_int(value) else repr(value)
    except RecursionError:          # pragma: no cover - a self-referencing value
        text = f"<{type(value).__name__}>"
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 4] + " ..."


#: Characters never written to a terminal as they are: C0 and C1 controls (escape
#: sequences retitle windows, clear screens, forge lines), DEL, the line and paragraph
#: separators and the bidirectional overrides and isolates (text that reads backwards).
_UNPRINTABLE = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029\u202a-\u202e\u2066-\u2069]")


def _is_long_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**24


def _short_int(value: int) -> str:
    """A huge integer as ``[-]d.dde+N`` (computed without ``str``, which refuses an integer of more
    than 4300 digits)."""
    v = abs(value)
    e = max(2, int(v.bit_length() * 0.30102999566398) - 1)
    while v // 10**e >= 1000:
        e += 1
    while v // 10**e < 100:
        e -= 1
    lead = str(v // 10**e)
    return f"{'-' if value < 0 else ''}{lead[0]}.{lead[1:]}e+{e + 2}"


def printable(text: Any, keep: str = "") -> str:
    """``str(text)`` with control characters escaped as Python does (``\\x1b``,
    ``\\u202e``), except those in ``keep`` (``"\\n"`` for a multi-line table).
    Every name read from a file goes through it before it reaches a terminal."""
    def escape(m: re.Match) -> str:
        ch = m.group()
        return ch if ch in keep else ascii(ch)[1:-1]
    return _UNPRINTABLE.sub(escape, str(text))


def check_plain_data(data: Any, what: str = "the scenario data", max_depth: int = MAX_DEPTH) -> None:
    """Refuse a mapping handed to the Python API that YAML could not have produced
    safely: nesting deeper than :data:`MAX_DEPTH`, more than :data:`MAX_NODES`
    nodes, or a container inside itself.  Raises :class:`DkfsimError` (``what`` names
    the data in its message)."""
    count = 0
    stack: list[tuple[Any, int, tuple[int, ...]]] = [(data, 0, ())]     # (node, depth, ids of its ancestors)
    while stack:
        node, depth, path = stack.pop()
        count += 1
        if count > MAX_NODES:
            raise DkfsimError(f"{what} holds more than {MAX_NODES:,} values")
        children: Iterable[Any]
        if isinstance(node, dict):
            children = node.values()
        elif isinstance(node, (list, tuple)):
            children = node
        else:
            continue
        if depth >= max_depth:
            raise DkfsimError(f"{what} is nested deeper than {max_depth} levels")
        if id(node) in path:
            raise DkfsimError(f"{what} contains itself (a recursive structure)")
        inner = path + (id(node),)
        stack.extend((child, depth + 1, inner) for child in children)


def open_regular(path: str | os.PathLike, *, limit: int, what: str, missing: str = "file not found") -> BinaryIO:
    """``path`` opened for reading (binary), once it is known to be a regular file of at most
    ``limit`` bytes: how every file dkfsim reads is opened.

    The file is opened non-blocking (a FIFO cannot block the open) and its type and size are
    checked on the descriptor opened (``fstat``: no race between the check and the read).
    Raises :class:`DkfsimError` (message ``"<path>: <reason>"``, the path cut by :func:`shown`)
    for an empty path, a missing file, a directory, a FIFO, socket or device, a file over the
    limit, or a path that cannot be opened (too long, no permission); ``missing`` is the
    message for a file that does not exist.
    """
    raw = os.fspath(path)
    label = shown(raw)
    if not str(raw).strip():
        raise DkfsimError(f"empty path: give the {what} to read")
    try:
        fd = os.open(raw, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise DkfsimError(f"{label}: {missing}") from None
    except (OSError, ValueError) as err:        # (ValueError: a NUL byte in the path)
        raise DkfsimError(f"{label}: cannot read it ({getattr(err, 'strerror', None) or err})") from None
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise DkfsimError(f"{label}: is a directory, not a {what}")
        if not stat.S_ISREG(st.st_mode):
            raise DkfsimError(f"{label}: not a regular file (a FIFO, socket or device); give a {what}")
        if st.st_size > limit:
            raise DkfsimError(f"{label}: {st.st_size:,} bytes, more than the {limit:,} a {what} may "
                              "have; is it the right file?")
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_text(path: str | os.PathLike, *, limit: int, what: str, missing: str = "file not found") -> str:
    """The UTF-8 text of a regular file of at most ``limit`` bytes (:func:`open_regular`'s
    checks; bytes that are not UTF-8 are a :class:`DkfsimError` too)."""
    label = shown(os.fspath(path))
    with open_regular(path, limit=limit, what=what, missing=missing) as fh:
        try:
            raw = fh.read(limit + 1)
        except OSError as err:
            raise DkfsimError(f"{label}: cannot read it ({err.strerror})") from None
    if len(raw) > limit:                 # grew since it was opened
        raise DkfsimError(f"{label}: more than the {limit:,} bytes a {what} may have")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise DkfsimError(f"{label}: not a UTF-8 text file ({err.reason} at byte {err.start})") \
            from None


def check_regular_file(path: Path, *, limit: int, what: str) -> None:
    """:func:`open_regular`'s checks without reading, for a file a library opens by its name
    (SQLite, pyarrow): the descriptor is opened and closed again."""
    open_regular(path, limit=limit, what=what).close()


def read_json(path: str | os.PathLike, *, what: str, limit: int = MAX_JSON_BYTES) -> Any:
    """The data of a JSON file someone may have tampered with, non-finite numbers read back
    (:func:`dkfsim.core.encoding.from_json`).

    Refused with a :class:`DkfsimError` naming the file: what :func:`read_text` refuses,
    text that is not JSON, nesting deeper than :data:`MAX_JSON_DEPTH` (checked on the text
    before parsing, so a thousand-level file cannot exhaust the parser's stack) or more
    than :data:`MAX_NODES` values.
    """
    return parse_json(read_text(path, limit=limit, what=what), os.fspath(path), what)


def parse_json(text: Any, label: str, what: str) -> Any:
    """JSON ``text`` read from a file or a database cell someone may have tampered with, with
    :func:`read_json`'s checks; ``label`` names where it was read in messages."""
    if not isinstance(text, str):
        raise DkfsimError(f"{label}: expected JSON text, got {type(text).__name__} {clip(text)}")
    if _json_depth(text) > MAX_JSON_DEPTH:
        raise DkfsimError(f"{label}: nested deeper than {MAX_JSON_DEPTH} levels; not a {what} dkfsim "
                          "wrote")
    try:
        data = json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise DkfsimError(f"{label}: not valid JSON ({clip(str(exc), 120)})") from None
    check_plain_data(data, f"{label}: the {what}", MAX_JSON_DEPTH)
    return from_json(data)


def _json_depth(text: str) -> int:
    """The deepest bracket nesting of JSON ``text`` (brackets inside strings skipped), in time
    and memory linear in its length: strings are removed by a pattern that never backtracks (an
    unterminated one runs to the end), then the nesting is the running sum of the brackets
    left, taken a few million at a time."""
    brackets = _NOT_BRACKET.sub("", _JSON_STRING.sub("", text)).encode("ascii")
    steps = _STEP[np.frombuffer(brackets, dtype=np.uint8)]
    depth = best = 0
    for i in range(0, len(steps), _CHUNK):
        run = np.cumsum(steps[i:i + _CHUNK], dtype=np.int64) + depth
        best, depth = max(best, int(run.max())), int(run[-1])
    return best


#: A JSON string: possessive, so that its match never backtracks (the earlier pattern kept a
#: backtracking entry per character: 4.8 GB for a 40 MB string).
_JSON_STRING = re.compile(r'"[^"\\]*+(?:\\.[^"\\]*+)*+(?:"|\\?\Z)', re.DOTALL)
_NOT_BRACKET = re.compile(r"[^\[\]{}]+")
_STEP = np.zeros(256, dtype=np.int8)
_STEP[[ord("["), ord("{")]] = 1
_STEP[[ord("]"), ord("}")]] = -1
_CHUNK = 1 << 22
