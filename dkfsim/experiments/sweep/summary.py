"""A sweep's answer on disk: ``<database stem>.summary.csv`` beside the database.

``dkfsim sweep`` writes it when the sweep is complete (and ``dkfsim plot SWEEP``
draws from the same numbers: :mod:`.grid`); this module reads a
database or its export (``.csv``, ``.parquet``) and writes the summary: per grid
point, estimate and component, the mean and 95 % interval over runs of the MSE,
the ANEES with its t-interval over runs and consistency verdict, the traffic per tick, and
the paired difference and ratio of the MSE to a reference estimate.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from dkfsim.config.results import sweep_rows, validate
from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import optional
from dkfsim.core.files import check_regular_file, open_regular
from dkfsim.core.folders import write_csv
from dkfsim.experiments.sweep.definition import KEY_COLUMNS, is_database
from dkfsim.experiments.sweep.grid import summarize
from dkfsim.experiments.sweep.results import read_results

#: Columns of an export that are text whatever they look like.
TEXT_COLUMNS = ("param_hash", "estimate", "component")
#: An export (or summary) is at most this big when read back for a plot (bytes).
MAX_TABLE_BYTES = 1 << 31


def summary_path(db) -> Path:
    """Where the summary of the database ``db`` goes: ``<stem>.summary.csv`` beside it."""
    db = Path(db)
    return db.with_name(db.stem + ".summary.csv")


def _cell(text: str):
    """A cell of an exported CSV back as a value: empty -> None, numbers as numbers,
    JSON lists and mappings as data, anything else as text."""
    if text == "":
        return None
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        pass
    if text[:1] in "[{":
        try:
            return json.loads(text)
        except ValueError:
            pass
    return text


def read_table(path) -> tuple[list[str], list[list]]:
    """``(columns, rows)`` of a sweep database or of its export (``.csv`` / ``.parquet``)."""
    p = Path(path)
    if not p.exists():
        raise DkfsimError(f"{path}: no such file (give a sweep database or its --export file)")
    if is_database(p):
        return read_results(p)
    suffix = p.suffix.lower()
    if suffix == ".csv":
        try:
            with io.TextIOWrapper(open_regular(p, limit=MAX_TABLE_BYTES, what="sweep export"), newline="",
                                  encoding="utf-8") as fh:
                reader = csv.reader(fh)
                columns = next(reader, None) or []
                text = [c in TEXT_COLUMNS for c in columns]      # (a hash of digits stays text)
                rows = [[c if t else _cell(c) for c, t in zip(row, text)] + [_cell(c) for c in row[len(text):]]
                        for row in reader]
        except (OSError, UnicodeDecodeError, csv.Error) as exc:
            raise DkfsimError(f"{path}: cannot read as CSV ({exc})") from None
    elif suffix in (".parquet", ".pq"):
        pq = optional("pyarrow.parquet")
        check_regular_file(p, limit=MAX_TABLE_BYTES, what="sweep export")
        try:
            table = pq.read_table(p)
        except Exception as exc:             # pyarrow raises many kinds for a bad file
            raise DkfsimError(f"{path}: cannot read as Parquet ({exc})") from None
        columns = list(table.column_names)
        data = table.to_pydict()
        rows = [[data[c][i] for c in columns] for i in range(table.num_rows)]
    else:
        raise DkfsimError(f"{path}: neither a sweep database nor a .csv / .parquet export")
    if not columns or any(c not in columns for c in KEY_COLUMNS):
        raise DkfsimError(f"{path}: not a sweep export (the columns "
                          f"{', '.join(KEY_COLUMNS)} are missing)")
    columns = list(columns)
    if len(set(columns)) != len(columns):
        raise DkfsimError(f"{path}: a column name appears twice")
    for i, row in enumerate(rows):
        if len(row) != len(columns):
            raise DkfsimError(f"{path}: row {i + 1} has {len(row)} cells for {len(columns)} columns")
    # The rows as a database's (an export may have been edited): names, run and seed, numbers.
    start = columns.index("param_hash")
    metrics = tuple(c for c in columns[start:] if c not in KEY_COLUMNS)
    validate(sweep_rows(metrics), [dict(zip(columns[start:], r[start:])) for r in rows], f"{path} (row)")
    return columns, rows


def write_summary(db, to=None, relative_to: str | None = None, table=None) -> tuple[Path, int]:
    """Summarize the sweep database (or export) ``db`` into ``to`` (default
    :func:`summary_path`), atomically; return ``(path, number of rows)``.  ``relative_to``:
    the reference estimate of the paired columns (default ``centralized``); ``table``: the
    ``(columns, rows)`` of ``db`` when already read."""
    columns, rows = read_table(db) if table is None else table
    columns, rows = summarize(columns, rows, relative_to=relative_to)
    to = Path(to) if to is not None else summary_path(db)
    try:
        write_csv(to, columns, rows)
    except OSError as exc:
        raise DkfsimError(f"{to}: cannot write the sweep summary ({exc.strerror})") from None
    return to, len(rows)
