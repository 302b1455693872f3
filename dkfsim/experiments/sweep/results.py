"""Reading a sweep database back: tidy rows in a fixed order, exported as CSV or Parquet.

The order (parameter set in grid order, run, estimate, component) makes an export
byte-identical whatever executor, worker count or interruptions produced the database.
See :mod:`dkfsim.experiments.sweep` and docs/design.md.
"""

from __future__ import annotations

import os
from pathlib import Path

from dkfsim.config.results import sweep_rows, validate
from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import optional
from dkfsim.core.folders import write_csv
from dkfsim.core.registry import METRICS
from dkfsim.experiments.sweep.definition import KEY_COLUMNS, canonical_json
from dkfsim.experiments.sweep.store import SweepDB, damaged, quote_name


# =========================================================================== reading, export
def read_results(db: str | os.PathLike) -> tuple[list[str], list[list]]:
    """``(columns, rows)`` of a sweep database, sorted by (parameter set in grid order,
    run, estimate in output order, component in state order): the grid values first
    (one column per grid key), then ``param_hash, run, seed, estimate, component`` and
    the metrics in registry order -- the tidy schema of every output.  Every row is
    checked (:func:`dkfsim.config.results.sweep_row_model`): a database may come from anyone."""
    store = SweepDB(db, readonly=True)
    try:
        definition = store.definition
        grid_keys = [k for k, _ in definition["grid"]]
        values = {p["param_hash"]: p["values"] for p in store.params()}
        with damaged(store.path):
            stored = [c for c in store.columns() if c not in KEY_COLUMNS]
            order = list(METRICS.names())
            metric_cols = sorted(stored, key=lambda c: (order.index(c) if c in order else len(order), c))
            select = ", ".join(f"r.{quote_name(c)}" for c in KEY_COLUMNS + tuple(metric_cols))
            # rowid: the order the task's rows were written in (estimates, then components).
            cur = store.conn.execute(
                f"SELECT {select} FROM results r JOIN params p ON p.param_hash = r.param_hash "
                "ORDER BY p.idx, r.run, r.rowid")
            raw = cur.fetchall()
    finally:
        store.close()
    names = list(KEY_COLUMNS) + metric_cols
    validate(sweep_rows(tuple(metric_cols)), [dict(zip(names, r)) for r in raw], f"{db} (table results, row)")
    rows = [[values[r[0]].get(k) for k in grid_keys] + list(r) for r in raw]
    taken = set(KEY_COLUMNS) | set(metric_cols)
    names = [k if k not in taken else f"param:{k}" for k in grid_keys]
    return names + list(KEY_COLUMNS) + metric_cols, rows


def export_format(to: str | os.PathLike) -> str:
    """The format (``.csv`` or ``.parquet``) of an export file name; refused before any work
    when unknown, or when pyarrow, needed for parquet, is missing."""
    suffix = Path(to).suffix.lower()
    if suffix not in (".csv", ".parquet", ".pq"):
        raise DkfsimError(f"--export {to}: unknown format {suffix or '(no suffix)'!r}; "
                          "use a .csv or .parquet file name")
    if suffix != ".csv":
        optional("pyarrow")
    return ".csv" if suffix == ".csv" else ".parquet"


def export(db: str | os.PathLike, to: str | os.PathLike, table=None) -> tuple[Path, int]:
    """Write the results of ``db`` to ``to`` (``.csv`` or ``.parquet``), sorted
    by key (see :func:`read_results`); return ``(path, number of rows)``.  ``table``: the
    ``(columns, rows)`` of ``db`` when already read."""
    to = Path(to)
    suffix = export_format(to)
    columns, rows = read_results(db) if table is None else table
    try:
        to.parent.mkdir(parents=True, exist_ok=True)
        if suffix == ".csv":
            write_csv(to, columns, rows)
        else:
            _write_parquet(to, columns, rows)
    except OSError as exc:
        raise DkfsimError(f"--export {to}: cannot write ({exc.strerror})") from None
    return to, len(rows)


def _write_parquet(path: Path, columns, rows) -> None:
    pa, pq = optional("pyarrow"), optional("pyarrow.parquet")
    arrays = []
    for j, _name in enumerate(columns):
        col = [row[j] for row in rows]
        if any(isinstance(v, (list, dict)) for v in col):
            col = [None if v is None else canonical_json(v) for v in col]
        try:
            arr = pa.array(col)
        except (pa.ArrowInvalid, pa.ArrowTypeError):
            arr = pa.array([None if v is None else canonical_json(v) for v in col], type=pa.string())
        arrays.append(arr)
    table = pa.Table.from_arrays(arrays, names=list(columns))
    tmp = path.with_name(path.name + ".tmp")
    pq.write_table(table, tmp)
    os.replace(tmp, path)

