"""Parameter sweeps: ``dkfsim sweep SWEEP.yaml``.

A sweep file names a scenario, a grid of scenario keys (dotted paths, as
``--set``) whose cartesian product gives the *parameter sets*, fixed
overrides, and a number of Monte Carlo runs per parameter set::

    scenario: paper_case1.yaml          # relative to the sweep file
    grid:
      links.default.latency.d_t: [0, 1, 2, 3, 4]
      protocol: [tree, flood]
    set: ["steps=300", "baselines=[centralized]"]
    runs: 20
    burn_in: null                       # rows; null = 10 % of the ticks
    output: results.sqlite              # default: <sweep file stem>.sqlite beside it

A *task* is (parameter set, run ``r``); run ``r`` uses seed
``derive_seed(base seed of the parameter set, r)``
(:func:`dkfsim.experiments.montecarlo.derive_seed`) and is scored by
:func:`dkfsim.experiments.montecarlo.run_rows`.  Workers only compute
(:mod:`dkfsim.experiments.executors`); this process writes every result into one SQLite
file, one transaction per task, so a task's rows are there entirely or not
at all.  Re-running the same command after an interruption (Ctrl-C,
``kill -9``, a lost cluster) skips the tasks already in the file.

Every part of a sweep but its figures and its report page is here (those draw, so they are in
:mod:`dkfsim.report.sweep`): :mod:`.definition` (the sweep file, validated by the schema
:class:`dkfsim.config.sweep.SweepFile`, and its parameter sets), :mod:`.store` (the database),
:mod:`.run` (running what is left), :mod:`.results` (reading it back, exporting), :mod:`.grid`
(the summary's numbers: mean and interval per grid point) and :mod:`.summary` (the summary
file, and reading a database or its export as one table).

Decisions:

* **The tidy rows every output shares**: one row per (parameter set, run,
  estimate, state component), every registered metric a column
  (:func:`dkfsim.analysis.metrics.score_scored`), the grid values in front.  NaN
  (not applicable) is stored as NULL (SQLite has no NaN) and exported as an
  empty cell / Parquet null.
* **The file stores its sweep definition** (grid, ``set``, ``runs``,
  ``burn_in`` and the hash of every resolved parameter set's scenario) and
  refuses to resume from a different one, including a changed scenario file
  that changes what a parameter set simulates.  Editing comments, moving the
  files or changing ``output`` does not matter.
* ``param_hash`` is the sha256 (first 20 hex digits) of the canonical JSON of
  the parameter set's grid values, so it does not depend on the grid's order.
* Tasks are submitted run-major (run 0 of every parameter set, then run 1,
  ...), so an interrupted sweep holds a balanced picture.
* Exports are sorted by (parameter set in grid order, run, estimate, component), so the
  file is byte-identical whatever executor, worker count or interruptions
  produced the database.
* One process at a time may write a database (an advisory lock on the file);
  a second ``dkfsim sweep`` on it stops with a clear message.
"""

from __future__ import annotations

from dkfsim.experiments.sweep.definition import (
                                                 DB_FORMAT,
                                                 KEY_COLUMNS,
                                                 SWEEP_KEYS,
                                                 ParameterSet,
                                                 Sweep,
                                                 is_database,
                                                 load_sweep,
)
from dkfsim.experiments.sweep.grid import summarize
from dkfsim.experiments.sweep.results import export, read_results
from dkfsim.experiments.sweep.run import SweepReport, estimate_tasks, run_sweep, run_task
from dkfsim.experiments.sweep.store import SCHEMA, SweepDB, tasks_done
from dkfsim.experiments.sweep.summary import read_table, summary_path, write_summary

__all__ = ["DB_FORMAT", "KEY_COLUMNS", "SCHEMA", "SWEEP_KEYS", "ParameterSet", "Sweep", "SweepDB",
           "SweepReport", "estimate_tasks", "export", "is_database", "load_sweep",
           "read_results", "read_table", "run_sweep", "run_task", "summarize", "summary_path", "tasks_done",
           "write_summary"]
