"""What a run returns and writes (docs/design.md §8).

:class:`RunResult` holds the arrays of a run (a mapping: ``res["x_local"]``),
the names of its estimates, its packet counts and each estimator's traffic,
and writes a result folder: ``run.npz`` (the arrays; a pure function of the
scenario and its seed, bit-identical across runs and worker counts),
``rows.csv`` (the tidy rows every output shares, one per estimate and state
component: :func:`dkfsim.analysis.metrics.score_scored`) and ``summary.json`` (the
same numbers, the counts, the scenario, versions and the wall time).
"""

from __future__ import annotations

import platform
from collections.abc import Mapping
from pathlib import Path

import networkx
import numpy as np
import scipy
import simpy

from dkfsim.analysis.frames import rows_frame, run_dataset
from dkfsim.analysis.metrics import default_burn_in, mse_per_component, row_columns, score_scored, scored
from dkfsim.config.dynamics import component_names
from dkfsim.config.load import scenario_hash, stored_scenario
from dkfsim.config.results import RunSummary, validate
from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import clip, read_json
from dkfsim.core.folders import staged, write_csv, write_json
from dkfsim.core.npzfile import NpzFile
from dkfsim.core.resources import FULL_LOG_LIMIT, SAVE_MODES, SaveMode, resolve_save_mode  # noqa: F401  (re-exported)
from dkfsim.core.version import __version__

#: ``run.npz`` keys that start with ``x_`` but are not estimates.
NOT_ESTIMATES = ("x_final", "x0_mean")


def versions() -> dict:
    return {"dkfsim": __version__, "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "simpy": simpy.__version__, "networkx": networkx.__version__}


def estimate_names(arrays: Mapping) -> list[str]:
    """The estimates a run's arrays hold (``x_<name>``), the DKF's first."""
    names = [k[2:] for k in arrays if k.startswith("x_") and k not in NOT_ESTIMATES]
    first = [n for n in ("fused", "local") if n in names]
    return first + [n for n in names if n not in first]


class RunResult(Mapping):
    """Arrays, estimates, counts and facts of one run; a read-only mapping of the arrays.

    ``estimates``: names in output order; ``traffic``: each estimate's
    estimator counts (``None``: no network model); ``counts``: the scenario's
    DKF packet counts (``sent``, ``delivered``, ``lost``, ``late``,
    ``per_link``, ...); ``facts``: side facts of the other estimators.  ``saved``: for a
    folder read without arrays (``--save summary``), ``{"folder", "burn_in", "rows"}`` of its
    ``summary.json``, which :meth:`rows`, :meth:`to_frame` and :meth:`metrics` return.
    """

    def __init__(self, scenario, arrays: dict, counts: dict, info: dict, *, estimates=None,
                 traffic: dict | None = None, facts: dict | None = None, saved: dict | None = None):
        self.scenario = scenario
        self.saved = saved
        self.arrays = arrays
        self.counts = counts
        self.info = info
        self.estimates = list(estimates) if estimates is not None else estimate_names(arrays)
        self.traffic = traffic or {}
        self.facts = facts or {}

    def __getitem__(self, key):
        return self.arrays[key]

    def __iter__(self):
        return iter(self.arrays)

    def __len__(self):
        return len(self.arrays)

    def __getattr__(self, key):
        arrays = self.__dict__.get("arrays", {})
        if key in arrays:
            return arrays[key]
        raise AttributeError(key)

    def __repr__(self) -> str:
        sc = self.scenario
        head = (f"RunResult {sc.name}: {sc.steps} ticks, {sc.n} nodes, seed {sc.seed}, "
                f"L = {self.info.get('buffer_length')}; {len(self.arrays)} arrays")
        if "truth" not in self.arrays:
            return f"<{head}; estimates {', '.join(self.estimates)}>"
        m = self.metrics()
        lines = [head, f"  MSE after {m['burn_in']} burn-in rows ({', '.join(self.components)}):"]
        width = max(len(n) for n in self.estimates)
        lines += [f"    {n.ljust(width)}  " + "  ".join(f"{v:.4g}" for v in m[n]) for n in self.estimates]
        c = self.counts
        if "sent" in c:
            lines.append(f"  packets: sent {c['sent']}, lost {c.get('lost')}, late contributions "
                         f"{c.get('late')}")
        if self.diverged:
            lines.append(f"  DIVERGED: {', '.join(self.diverged)}")
        return "<" + "\n".join(lines) + ">"

    def to_frame(self, burn_in: int | None = None):
        """The tidy rows (:meth:`rows`) as a pandas DataFrame, the columns of ``rows.csv``."""
        return rows_frame(self.rows(burn_in), row_columns())

    def to_xarray(self):
        """The arrays as an :class:`xarray.Dataset` with named dimensions (``tick``, ``node``,
        ``state``, ...; :func:`dkfsim.analysis.frames.run_dataset`)."""
        sc = self.scenario
        return run_dataset(self.arrays, self.components, sc.n,
                           attrs={"scenario": sc.name, "seed": int(sc.seed),
                                  "estimates": ", ".join(self.estimates)})

    @property
    def components(self) -> list[str]:
        return component_names(self.scenario.model.kind, self.scenario.nx)

    def _burn(self, burn_in: int | None) -> int:
        K = self.arrays["truth"].shape[0]
        return default_burn_in(K) if burn_in is None else int(burn_in)

    def saved_rows(self, burn_in: int | None = None) -> list[dict]:
        """The rows ``summary.json`` holds, for a run read without arrays (``--save summary``);
        a clear error when there are none or ``burn_in`` asks for another burn-in."""
        if self.saved is None:
            raise DkfsimError(f"run {self.scenario.name}: it holds no arrays (no run.npz) and no "
                              "saved rows: nothing to score")
        where, burn = self.saved["folder"], self.saved["burn_in"]
        if burn_in is not None and int(burn_in) != burn:
            raise DkfsimError(f"{where}: saved with --save summary, so it holds the rows after "
                              f"{burn} burn-in rows only and no arrays to score burn-in {burn_in}; "
                              "run it again with --save estimates (or full) to choose the burn-in")
        return [dict(row) for row in self.saved["rows"]]

    def metrics(self, burn_in: int | None = None) -> dict:
        """MSE per state component after the burn-in, by estimate name."""
        if "truth" not in self.arrays:
            rows = self.saved_rows(burn_in)
            assert self.saved is not None                  # saved_rows raised otherwise
            saved: dict = {"burn_in": self.saved["burn_in"]}
            for name in self.estimates:
                saved[name] = [r["mse"] for c in self.components for r in rows
                               if r["estimate"] == name and r["component"] == c]
            return saved
        burn = self._burn(burn_in)
        out: dict = {"burn_in": burn}
        with np.errstate(all="ignore"):       # diverged estimates give inf / nan, reported
            for name in self.estimates:
                out[name] = mse_per_component(self.arrays[f"x_{name}"], self.arrays["truth"], burn).tolist()
        return out

    def scored(self, burn_in: int | None = None) -> dict:
        """Each estimate as the metrics see it (:class:`~dkfsim.analysis.metrics.Scored`), by name."""
        burn = self._burn(burn_in)
        return {name: scored(self.arrays[f"x_{name}"], self.arrays.get(f"P_{name}"),
                             self.arrays["truth"], self.traffic.get(name), burn)
                for name in self.estimates}

    def rows(self, burn_in: int | None = None, scored_: dict | None = None) -> list[dict]:
        """The tidy rows of this run (``run`` 0): one per estimate and state component.
        ``scored_``: :meth:`scored` when the caller has it already (and reuses its NEES).
        A run read without arrays (``--save summary``) returns the rows it saved."""
        if "truth" not in self.arrays and scored_ is None:
            return self.saved_rows(burn_in)
        scored_ = self.scored(burn_in) if scored_ is None else scored_
        components = self.components
        out = []
        for name, s in scored_.items():
            for row in score_scored(name, s, components):
                out.append({"run": 0, "seed": int(self.scenario.seed), **row})
        return out

    @property
    def diverged(self) -> list[str]:
        """Estimates (``x_*`` arrays) holding non-finite values: the filter diverged."""
        return [f"x_{n}" for n in self.estimates if not np.isfinite(self.arrays[f"x_{n}"]).all()]

    def summary(self, burn_in: int | None = None) -> dict:
        sc = self.scenario
        counts = {k: v for k, v in self.counts.items() if k != "per_link"}
        traffic = {name: (None if t is None else {k: (_json_links(v) if k == "per_link" else v)
                                                  for k, v in t.items()})
                   for name, t in self.traffic.items()}
        return {
            "scenario": sc.name,
            "scenario_hash": scenario_hash(sc),
            "source": getattr(sc, "source", None),
            "seed": sc.seed,
            "steps": sc.steps,
            "protocol": sc.protocol,
            "weights": sc.weights,
            "fusion": sc.fusion,
            **{k: v for k, v in self.info.items()},
            "versions": versions(),
            "estimates": self.estimates,
            "metrics": self.metrics(burn_in),
            "rows": self.rows(burn_in),
            "diverged": self.diverged,
            "packets": counts,
            "per_link": _json_links(self.counts.get("per_link", [])),
            "traffic": traffic,
            "facts": self.facts,
            "scenario_config": sc.to_dict(),
        }

    def save(self, out_dir, burn_in: int | None = None) -> Path:
        """Write ``run.npz`` (unless the save mode is ``summary``), ``rows.csv`` and
        ``summary.json``.  The folder is replaced as a whole and atomically
        (:func:`dkfsim.core.folders.staged`): no file of an earlier run survives."""
        summary = self.summary(burn_in)
        with staged(out_dir, "run") as tmp:
            if self.info.get("save") != "summary":
                np.savez(tmp / "run.npz", **self.arrays)
            write_rows(tmp / "rows.csv", summary["rows"])
            write_json(tmp / "summary.json", summary)
        return Path(out_dir)


def _json_links(rows) -> list[dict]:
    """Per-link rows as summary.json keeps them (the link as a list)."""
    return [{**d, "link": list(d["link"])} for d in rows]


def write_rows(path, rows: list[dict]) -> None:
    """Tidy rows as CSV with the shared columns (:func:`dkfsim.analysis.metrics.row_columns`)."""
    columns = row_columns()
    write_csv(path, columns, ([row.get(c) for c in columns] for row in rows))


#: Keys of summary.json that are facts of the run (``RunResult.info``).
INFO_KEYS = ("buffer_length", "d_t", "d_g", "n_links", "wall_time_s", "save", "kernels",
             "node_rows", "exchange", "backend", "mobility")


def load_run(folder, *, data_files: bool = False) -> RunResult:
    """Read a folder written by ``dkfsim run`` (or :meth:`RunResult.save`) back into a RunResult.

    Everything read is checked first (docs/security.md): ``summary.json`` against
    :class:`dkfsim.config.results.RunSummary`, every array's header of ``run.npz``
    (numbers only, ``steps`` rows, within the memory budget) before its data.  The
    scenario is re-validated from the copy in ``summary.json`` as data
    (:func:`dkfsim.config.load.stored_scenario`: its ``plugins:`` key is never
    imported, and a ``file:`` key it holds is an error unless ``data_files=True``: a result
    you received may name any file of your machine; with it, relative data files resolve
    against the original scenario file's folder); the arrays are those of ``run.npz`` (none
    when the run was saved with ``--save summary``).  Raises :class:`DkfsimError`.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DkfsimError(f"{folder}: no such folder (give the folder dkfsim run wrote)")
    path = folder / "summary.json"
    data = read_json(path, what="summary.json")
    if not isinstance(data, dict) or "scenario_config" not in data or "packets" not in data:
        raise DkfsimError(f"{path}: not a summary written by dkfsim run (a Monte Carlo or maxdelay "
                          "folder? dkfsim.load reads every kind of result)")
    summary = validate(RunSummary, data, str(path)).model_dump()
    source = summary.get("source")
    scenario = stored_scenario(summary["scenario_config"], source=source, label=str(path), data_files=data_files)
    scenario.set_source(source)
    if scenario.steps != summary["steps"]:
        raise DkfsimError(f"{path}: steps is {summary['steps']} but its scenario_config says "
                          f"{scenario.steps}")
    arrays: dict = {}
    npz = folder / "run.npz"
    if npz.exists() or npz.is_symlink():
        with NpzFile(npz, "run.npz") as z:
            _check_arrays(z, scenario, summary["estimates"])
            arrays = z.read()
    counts = dict(summary["packets"])
    counts["per_link"] = [{**d, "link": tuple(d["link"])} for d in summary["per_link"]]
    info = {key: summary[key] for key in INFO_KEYS if key in summary}
    if info.get("mobility") is None:     # a run without mobility: no key (as it was written)
        info.pop("mobility", None)
    traffic = {name: (t if t is None or "per_link" not in t else
                      {**t, "per_link": [{**d, "link": tuple(d["link"])} for d in t["per_link"]]})
               for name, t in summary["traffic"].items()}
    saved = None
    if not arrays:
        saved = {"folder": str(folder), "burn_in": summary["metrics"]["burn_in"], "rows": summary["rows"]}
    return RunResult(scenario, arrays, counts, info, estimates=summary["estimates"],
                     traffic=traffic, facts=summary["facts"], saved=saved)


#: ``run.npz`` arrays with one row per tick (their first axis is ``steps``): whole names, then
#: prefixes.
PER_TICK_ARRAYS = ("t", "truth", "queue_length", "utilisation", "positions", "links_up")
PER_TICK = ("t", "truth", "x_", "P_", "y_", "z_", "Rc_")


def _check_arrays(z: NpzFile, scenario, estimates) -> None:
    """The headers of ``run.npz`` fit its scenario: numbers only, ``steps`` rows where an array
    has one per tick, the truth ``(steps, nx)``, an ``x_<name>`` for every estimate."""
    K, nx = scenario.steps, scenario.nx
    for key, h in z.headers.items():
        if not h.numeric:
            raise DkfsimError(f"{z.path}: array {clip(key)} holds {h.dtype} values, expected numbers")
        per_tick = key in PER_TICK_ARRAYS or (key.startswith(PER_TICK[2:]) and key not in NOT_ESTIMATES)
        if per_tick and (not h.shape or h.shape[0] != K):
            raise DkfsimError(f"{z.path}: array {clip(key)} has shape {h.shape}; the run has "
                              f"{K} ticks (steps in summary.json)")
    z.check_size(z.files)
    if "truth" in z and z.headers["truth"].shape != (K, nx):
        raise DkfsimError(f"{z.path}: array 'truth' has shape {z.headers['truth'].shape}, "
                          f"expected ({K}, {nx})")
    for name in estimates:
        if f"x_{name}" not in z:
            raise DkfsimError(f"{z.path}: no array x_{name} for the estimate {clip(name)} that "
                              "summary.json lists")
