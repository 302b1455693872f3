"""SUMO floating-car data: the vehicles' timed positions in a ``sumo --fcd-output`` file.

The file is ``<fcd-export><timestep time="…"><vehicle id="…" x="…" y="…"
speed="…" angle="…"/>…</timestep>…</fcd-export>``.  It is read in one
streaming pass (1 MiB at a time, no tree kept: files of any size fit in
memory as 24 bytes per vehicle sample) with defusedxml's expat parser, which
refuses document type declarations, entity declarations and external
references outright: a SUMO file has none, and they are how an XML file
attacks its reader (entity expansion "bombs", reading local files or URLs).
It is opened as every file dkfsim reads (:func:`~dkfsim.core.files.open_regular`:
a FIFO or a device is refused, never waited on).  A SUMO element is a few hundred
bytes: a stretch of :data:`MAX_ELEMENT_BYTES` without a ``>`` (an attribute or a text of
megabytes, which expat would buffer and re-scan at every chunk: quadratic time,
gigabytes) is refused before it is parsed; coordinates are at most :data:`MAX_COORDINATE`
metres and times :data:`~dkfsim.core.params.MAX_SECONDS` in magnitude, and no speed
between two samples may overflow.
Every problem is a :class:`~dkfsim.core.errors.DkfsimError` naming the file,
the line and what is wrong; a message quotes nothing of the file but a vehicle's id (at
most 40 characters, escaped) once the file has shown itself an FCD export: a scenario may
name any file, and its content is not to appear in a terminal or a log.
"""

from __future__ import annotations

import math
import os
from array import array
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from dkfsim.core.datafiles import DataFileError, file_key
from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import optional
from dkfsim.core.files import open_regular, printable
from dkfsim.core.params import MAX_SECONDS

_CHUNK = 1 << 20
#: Largest SUMO FCD file read (bytes): hours of a city's traffic.
MAX_FCD_BYTES = 1 << 34
#: Longest stretch of a file without a ``>`` (bytes): no element of a SUMO file comes near it.
MAX_ELEMENT_BYTES = 1 << 16
#: Largest coordinate (metres, either sign): beyond any road network's projection.
MAX_COORDINATE = 1e9


def _quoted(text: str) -> str:
    """At most 40 characters of a vehicle's id, escaped, as a message quotes them."""
    return repr(printable(text[:40]))


@dataclass(frozen=True)
class FcdData:
    """Every vehicle of one FCD file: ``vehicles[id] = (t, xy)``, ``t`` (N,) strictly
    increasing seconds of SUMO's clock, ``xy`` (N, 2) metres."""

    path: str
    vehicles: dict[str, tuple[np.ndarray, np.ndarray]]


class _Collector:
    """The parser's target: checks each element as it opens, keeps only numbers."""

    def __init__(self, name: str):
        self.name = name
        self.parser: Any = None       # expat's parser, set once it exists (for line numbers)
        self.depth = 0
        self.time: float | None = None
        self.samples: dict[str, tuple[array, array, array]] = {}

    def fail(self, what: str) -> NoReturn:
        line = self.parser.CurrentLineNumber if self.parser is not None else "?"
        raise DkfsimError(f"SUMO FCD file {self.name} line {line}: {what}")

    def number(self, attrib: dict, key: str, what: str, bound: float) -> float:
        raw = attrib.get(key)
        if raw is None:
            self.fail(f"{what} has no {key!r} attribute")
        try:
            value = float(raw)
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            self.fail(f"{what}: {key} is not a finite number")
        if abs(value) > bound:
            self.fail(f"{what}: {key} is beyond {bound:.3g} in magnitude")
        return value

    def start(self, tag: str, attrib: dict) -> None:
        self.depth += 1
        if self.depth == 1 and tag != "fcd-export":
            self.fail("the root element is not <fcd-export> (is this sumo --fcd-output?)")
        if tag == "timestep" and self.depth == 2:
            t = self.number(attrib, "time", "<timestep>", MAX_SECONDS)
            if self.time is not None and t <= self.time:
                self.fail(f"time goes backwards: timestep time={t!r} after time={self.time!r} "
                          "(timesteps must increase)")
            self.time = t
        elif tag == "vehicle" and self.depth == 3:
            vid = attrib.get("id")
            if not vid:
                self.fail("a <vehicle> without an id")
            what = f"vehicle {_quoted(vid)} at time {self.time!r}"
            x, y = self.number(attrib, "x", what, MAX_COORDINATE), self.number(attrib, "y", what, MAX_COORDINATE)
            ts, xs, ys = self.samples.setdefault(vid, (array("d"), array("d"), array("d")))
            if ts and ts[-1] == self.time:
                self.fail(f"vehicle {_quoted(vid)} appears twice in the timestep at time {self.time!r}")
            ts.append(self.time)
            xs.append(x)
            ys.append(y)

    def end(self, _tag: str) -> None:
        self.depth -= 1

    def close(self) -> None:
        return None


_CACHE: dict[tuple, FcdData] = {}
#: defusedxml's refusals, in words.
_REFUSED = {"DTDForbidden": "a document type declaration (<!DOCTYPE ...>)",
            "EntitiesForbidden": "an entity declaration (<!ENTITY ...>)",
            "ExternalReferenceForbidden": "an external reference",
            "NotSupportedError": "an XML feature it does not support"}


def read_fcd(path: str | os.PathLike) -> FcdData:
    """Read (and cache, on path, size and modification time) a SUMO FCD file."""
    path = Path(path)
    try:
        key = file_key(path)
    except DataFileError as err:
        raise DkfsimError(f"SUMO FCD file: {err}") from None
    if key not in _CACHE:
        _CACHE[key] = _parse(path)
    return _CACHE[key]


def _parse(path: Path) -> FcdData:
    defused = optional("defusedxml.ElementTree")
    errors = optional("defusedxml")
    collector = _Collector(path.name)
    parser = defused.DefusedXMLParser(target=collector, forbid_dtd=True, forbid_entities=True,
                                      forbid_external=True)
    collector.parser = parser.parser
    try:
        with open_regular(path, limit=MAX_FCD_BYTES, what="SUMO FCD file") as fh:
            run = 0                               # bytes since the last '>'
            while chunk := fh.read(_CHUNK):
                run = _check_elements(chunk, run, path.name)
                parser.feed(chunk)
            parser.close()
    except errors.DefusedXmlException as err:
        what = _REFUSED.get(type(err).__name__, type(err).__name__)
        raise DkfsimError(f"SUMO FCD file {path.name} line {collector.parser.CurrentLineNumber}: refused "
                          f"{what}: a SUMO FCD file has none, and they are how an XML file attacks its "
                          "reader (entity expansion, reading local files or URLs)") from None
    except defused.ParseError as err:
        raise DkfsimError(f"SUMO FCD file {path.name}: not well-formed XML: {err}") from None
    except OSError as err:
        raise DkfsimError(f"cannot read SUMO FCD file {path}: {err.strerror}") from None
    if collector.time is None:
        raise DkfsimError(f"SUMO FCD file {path.name} has no <timestep>")
    vehicles = {}
    for vid, (ts, xs, ys) in collector.samples.items():
        t, xy = np.frombuffer(ts), np.column_stack([np.frombuffer(xs), np.frombuffer(ys)])
        k = unbounded_segment(t, xy)
        if k is not None:
            raise DkfsimError(f"SUMO FCD file {path.name}: vehicle {_quoted(vid)} moves from time "
                              f"{float(t[k])!r} to {float(t[k + 1])!r} at a speed beyond any number (the times are "
                              "too close for the distance)")
        vehicles[vid] = (t, xy)
    return FcdData(str(path), vehicles)


def unbounded_segment(t: np.ndarray, xy: np.ndarray) -> int | None:
    """The first segment ``k`` (sample ``k`` to ``k + 1`` of positions ``xy`` at times ``t``) whose
    speed is beyond any float (its times too close for its distance), or whose times are not
    finite; None when there is none.  (Also what refuses a track or waypoints:
    :meth:`~dkfsim.components.trajectories.Polyline.unbounded`.)"""
    with np.errstate(all="ignore"):              # (checked here: no warning reaches the user)
        speed = np.hypot(*(np.diff(xy, axis=0) / np.diff(t)[:, None]).T)
        bad = ~np.isfinite(speed) | ~np.isfinite(t[1:]) | ~np.isfinite(t[:-1])
    return int(np.nonzero(bad)[0][0]) if bad.any() else None


def _check_elements(chunk: bytes, run: int, name: str) -> int:
    """Refuse a stretch of :data:`MAX_ELEMENT_BYTES` without a ``>`` (``run`` such bytes ended
    the previous chunk); the bytes without one that end this chunk."""
    pieces = chunk.split(b">")
    if run + len(pieces[0]) >= MAX_ELEMENT_BYTES or max(map(len, pieces[1:]), default=0) >= MAX_ELEMENT_BYTES:
        raise DkfsimError(f"SUMO FCD file {name}: {MAX_ELEMENT_BYTES:,} bytes or more without a '>' (an "
                          "element, attribute or text that long); not a SUMO FCD file")
    return run + len(chunk) if len(pieces) == 1 else len(pieces[-1])
