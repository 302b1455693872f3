"""``dkfsim.load(path)``: any result dkfsim wrote, read back as its result object.

A run folder gives a :class:`~dkfsim.engine.results.RunResult`
(:func:`~dkfsim.engine.results.load_run`), a Monte Carlo folder a
:class:`~dkfsim.experiments.montecarlo.MonteCarloResult`
(:func:`~dkfsim.experiments.montecarlo.load_montecarlo`), a sweep database (or its
``--export`` file) a :class:`SweepResult`; each has ``to_frame()``, the tidy rows as a
pandas DataFrame.  Every reader validates what it reads (docs/security.md): nothing is
imported or unpickled, a damaged or hostile file is one clear error.
"""

from __future__ import annotations

from pathlib import Path

from dkfsim.analysis.frames import rows_frame
from dkfsim.core.errors import DkfsimError
from dkfsim.engine.results import load_run
from dkfsim.experiments.montecarlo import load_montecarlo
from dkfsim.experiments.sweep import is_database
from dkfsim.experiments.sweep.grid import summarize
from dkfsim.experiments.sweep.summary import read_table


class SweepResult:
    """The rows of a sweep database (or of its export), read back and checked.

    ``columns``, ``rows``: the table of :func:`dkfsim.experiments.sweep.read_results`
    (grid columns, then the tidy columns).  :meth:`to_frame` gives it as a DataFrame,
    :meth:`summary` the summary (``<stem>.summary.csv``'s table) with the paired
    comparison to ``relative_to``.
    """

    def __init__(self, path, columns, rows):
        self.path = Path(path)
        self.columns = list(columns)
        self.rows = rows

    def __repr__(self) -> str:
        return (f"<SweepResult {self.path}: {len(self.rows)} rows; .to_frame(): the rows, "
                ".summary(relative_to=None): mean, 95 % interval, verdicts, paired comparison>")

    def to_frame(self):
        """Every row as a pandas DataFrame (the export's columns)."""
        return rows_frame(self.rows, self.columns)

    def summary(self, relative_to: str | None = None):
        """Per grid point, estimate and component (:func:`dkfsim.experiments.sweep.grid.summarize`)."""
        columns, rows = summarize(self.columns, self.rows, relative_to=relative_to)
        return rows_frame(rows, columns)


def load(path, *, data_files: bool = False):
    """The result at ``path``: a run folder (``RunResult``), a Monte Carlo folder
    (``MonteCarloResult``) or a sweep database / export file (:class:`SweepResult`).
    ``data_files``: open the files the stored scenario's ``file:`` keys name (only for a
    result you trust; :func:`~dkfsim.engine.results.load_run`).
    Raises :class:`DkfsimError` for anything else or anything damaged."""
    p = Path(path)
    if p.is_file() and (is_database(p) or p.suffix.lower() in (".csv", ".parquet", ".pq")):
        return SweepResult(p, *read_table(p))
    if p.is_dir():
        if (p / "runs.csv").is_file() or (p / "curves.npz").is_file():
            return load_montecarlo(p, data_files=data_files)
        if (p / "rows.csv").is_file() or (p / "run.npz").is_file():
            return load_run(p, data_files=data_files)
        if (p / "summary.json").is_file():
            return load_run(p, data_files=data_files)       # says what the summary is if it is not a run's
    if not p.exists():
        raise DkfsimError(f"{path}: no such file or folder")
    raise DkfsimError(f"{path}: not a result dkfsim wrote (a run folder: summary.json + rows.csv; "
                      "a Monte Carlo folder: summary.json + runs.csv + curves.npz; or a sweep "
                      "database .sqlite or its .csv / .parquet export)")
