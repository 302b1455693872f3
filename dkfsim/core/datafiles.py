"""Data files a scenario names: shipped datasets and the user's own tables.

Two ways to name a table of measurements (a latency trace, a recorded
track), and they cannot be mistaken for one another:

* ``dataset: cicv5g/urban_n8_v30_run01`` -- a dataset shipped inside the
  package (``dkfsim/data/<collection>/<name>.txt``; see the README there for
  its source and licence).  It works from any folder and any install.
* ``file: traces/mine.csv`` -- the user's own file; a relative path resolves
  against the scenario file's folder (the working directory for a scenario
  given as a mapping without ``base_dir``).

Tables are CSV (a comma in the first line) or whitespace separated, with
an optional header line; blank lines and lines starting with ``#`` are
skipped.  One reader (:func:`read_table`) serves every caller, so the
``empirical`` latency model and the ``truth`` track agree on what a table is.

A message about the user's own file names the file, the line and the column (its index,
or the name the scenario asked for) and quotes none of its content: a scenario may name
any file of the machine (``file: /etc/passwd``), and its first line is not to appear in a
terminal, a log or a report as "the columns".  A shipped dataset's header names are quoted
(the file is public, part of the package).
"""

from __future__ import annotations

import difflib
import os
import re
from dataclasses import dataclass
from pathlib import Path

from dkfsim.core.files import MAX_DATA_BYTES, clip, printable, read_text

#: Where shipped datasets live: ``DATA_DIR / collection / (name + ".txt")``.
DATA_DIR = Path(__file__).resolve().parents[1] / "data"
_SUFFIXES = (".txt", ".csv")


class DataFileError(ValueError):
    """A data file cannot be found or read; the message says why."""


def datasets() -> list[str]:
    """Names of the shipped datasets, ``collection/name``, sorted."""
    out = []
    for sub in sorted(p for p in DATA_DIR.iterdir() if p.is_dir()):
        out += [f"{sub.name}/{f.stem}" for f in sorted(sub.iterdir()) if f.suffix in _SUFFIXES]
    return out


def dataset_path(name: str) -> Path:
    """The file of a shipped dataset ``collection/name``; :class:`DataFileError` if unknown."""
    known = datasets()
    if name not in known:
        close = difflib.get_close_matches(str(name), known, n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise DataFileError(f"unknown dataset {name!r}{hint}; shipped datasets: {', '.join(known)}")
    collection, stem = name.split("/", 1)
    for suffix in _SUFFIXES:
        path = DATA_DIR / collection / (stem + suffix)
        if path.is_file():
            return path
    raise DataFileError(f"dataset {name!r} is listed but its file is missing")  # pragma: no cover


def resolve_data_file(file: str, base_dir: str | os.PathLike | None = None) -> tuple[Path | None, list[Path]]:
    """The user's file a scenario names, and the place(s) tried.

    Absolute paths are used as they are; a relative path is looked up in
    ``base_dir`` (the scenario file's folder; the working directory when
    ``None``) and nowhere else.
    """
    path = Path(os.path.expanduser(str(file)))
    cand = path if path.is_absolute() else (Path(base_dir) if base_dir is not None else Path.cwd()) / path
    # Anything that exists is returned: reading it says if it is not a regular file.
    return (cand.resolve() if cand.exists() else None), [cand]


def locate(file: str | None, dataset: str | None, base_dir) -> tuple[Path, str]:
    """The path of a ``file`` / ``dataset`` pair (exactly one given) and the key it came from.

    Raises :class:`DataFileError` naming what was tried.
    """
    if (file is None) == (dataset is None):
        raise DataFileError("give exactly one of file (your own table) or dataset (a shipped one: "
                            + ", ".join(datasets()) + ")")
    if dataset is not None:
        return dataset_path(dataset), "dataset"
    assert file is not None               # (exactly one is given)
    path, tried = resolve_data_file(file, base_dir)
    if path is None:
        raise DataFileError("file not found (tried " + ", ".join(str(t) for t in tried) + ")")
    return path, "file"


def norm_name(name: str) -> str:
    """A column header reduced to lower-case letters and digits (``delay(ms)`` -> ``delayms``)."""
    return re.sub(r"[^0-9a-z]", "", str(name).lower())


@dataclass(frozen=True)
class Table:
    """A text table: its header (``None`` when the first line is all numbers) and data lines."""

    path: Path
    header: list[str] | None
    lines: list[tuple[int, list[str]]]          # (line number, fields)

    @property
    def shipped(self) -> bool:
        """A dataset of the package (its content may be quoted in messages)."""
        return self.path.resolve().is_relative_to(DATA_DIR)

    def _quote(self, text: str) -> str:
        """Text of a shipped dataset as a message quotes it: escaped, at most 40 characters."""
        return clip(printable(text), 40)

    def column_index(self, column: str | int) -> int:
        """Index of a column by header name (exact, then ignoring case and
        punctuation, so ``delay_ms`` finds ``delay(ms)``) or by 0-based index."""
        width = len(self.header) if self.header is not None else len(self.lines[0][1])
        if isinstance(column, int):
            if column >= width:
                raise DataFileError(f"column index {column} is out of range: {self.path.name} has "
                                    f"{width} columns")
            return column
        if self.header is None:
            raise DataFileError(f"{self.path.name} has no header line; give column as a 0-based index")
        if column in self.header:
            return self.header.index(column)
        normed = [norm_name(h) for h in self.header]
        if norm_name(column) and norm_name(column) in normed:
            return normed.index(norm_name(column))
        asked = clip(printable(column), 60)
        if not self.shipped:
            raise DataFileError(f"no column {asked} in {self.path.name}: its header line has {width} "
                                f"name{'s' * (width != 1)} (a data file's content is not shown: open the "
                                "file to see them), or give column as a 0-based index")
        close = difflib.get_close_matches(str(column), self.header, n=1)
        hint = f" (did you mean {self._quote(close[0])}?)" if close else ""
        raise DataFileError(f"no column {asked} in {self.path.name}; its columns are: "
                            + ", ".join(self._quote(h) for h in self.header[:20]) + hint)

    def floats(self, idx: int) -> list[tuple[int, float]]:
        """``(line number, float)`` of column ``idx`` in every data line."""
        out = []
        for no, fields in self.lines:
            if idx >= len(fields):
                raise DataFileError(f"{self.path.name} line {no}: has {len(fields)} fields, "
                                    f"no column {idx}")
            try:
                out.append((no, float(fields[idx])))
            except ValueError:
                value = f" ({self._quote(fields[idx])})" if self.shipped else ""
                raise DataFileError(f"{self.path.name} line {no}: column {idx}{value} is not a number") from None
        return out


_TABLES: dict[tuple, Table] = {}


def _numeric(field: str) -> bool:
    try:
        float(field)
        return True
    except ValueError:
        return False


def file_key(path: Path) -> tuple[str, int, int]:
    """``(path, modification time, size)``: what a cache of the file's contents is keyed on."""
    try:
        st = path.stat()
    except OSError as err:
        raise DataFileError(f"cannot read {path}: {err.strerror}") from None
    return str(path), st.st_mtime_ns, st.st_size


def read_table(path: str | os.PathLike) -> Table:
    """Read a table (cached on path, modification time and size)."""
    path = Path(path)
    key = file_key(path)
    table = _TABLES.get(key)
    if table is not None:
        return table
    try:
        text = read_text(path, limit=MAX_DATA_BYTES, what="data file")
    except Exception as err:           # DkfsimError from read_text: keep its reason
        raise DataFileError(str(err)) from None
    raw = [(no, line.strip()) for no, line in enumerate(text.splitlines(), 1)]
    raw = [(no, t) for no, t in raw if t and not t.startswith("#")]
    if not raw:
        raise DataFileError(f"{path.name} holds no data")
    comma = "," in raw[0][1]
    split = (lambda t: [f.strip() for f in t.split(",")]) if comma else str.split
    first = split(raw[0][1])
    header = None if all(_numeric(f) for f in first) else first
    lines = [(no, split(t)) for no, t in (raw[1:] if header is not None else raw)]
    if not lines:
        raise DataFileError(f"{path.name} has a header but no data rows")
    table = Table(path, header, lines)
    _TABLES[key] = table
    return table
