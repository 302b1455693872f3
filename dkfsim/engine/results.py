"""What a run returns and writes (docs/design.md §8).

:class:`RunResult` holds the arrays of a run (a mapping: ``res["x_local"]``),
its packet counts and a few facts about it, and writes ``run.npz`` and
``summary.json``.  The npz is a pure function of the scenario and its seed:
bit-identical across runs and worker counts.  ``summary.json`` adds the wall
time and versions, which are not.
"""

from __future__ import annotations

import platform
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from dkfsim.core.errors import DkfsimError
from dkfsim.analysis.metrics import default_burn_in, run_metrics
from dkfsim.core.folders import staged, write_json

SAVE_MODES = ("auto", "full", "estimates", "summary")

#: ``save: auto`` keeps the (n, n, K) arrival log only while it stays below this
#: many entries (160 MB); beyond, it saves the estimates only.
FULL_LOG_LIMIT = 20_000_000


def resolve_save_mode(save: str, n: int, K: int) -> str:
    if save not in SAVE_MODES:
        raise DkfsimError(f"--save: unknown mode {save!r}; choose one of {', '.join(SAVE_MODES)}")
    if save == "auto":
        return "full" if n * n * K <= FULL_LOG_LIMIT else "estimates"
    return save


def versions() -> dict:
    import networkx
    import scipy
    import simpy

    from dkfsim import __version__
    return {"dkfsim": __version__, "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "simpy": simpy.__version__, "networkx": networkx.__version__}


class RunResult(Mapping):
    """Arrays, counts and facts of one run; a read-only mapping of the arrays."""

    def __init__(self, scenario, arrays: dict, counts: dict, info: dict):
        self.scenario = scenario
        self.arrays = arrays
        self.counts = counts
        self.info = info

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

    def metrics(self, burn_in: int | None = None) -> dict:
        K = self.arrays["truth"].shape[0]
        with np.errstate(all="ignore"):       # diverged estimates give inf / nan, reported
            return run_metrics(self.arrays, default_burn_in(K) if burn_in is None else burn_in)

    @property
    def diverged(self) -> list[str]:
        """Estimates (``x_*`` arrays) holding non-finite values: the filter diverged."""
        return [key for key, val in self.arrays.items()
                if key.startswith("x_") and key != "x0_mean" and not np.isfinite(val).all()]

    def summary(self, burn_in: int | None = None) -> dict:
        from dkfsim.config.schema import scenario_hash
        sc = self.scenario
        counts = {k: v for k, v in self.counts.items() if k != "per_link"}
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
            "metrics": self.metrics(burn_in),
            "diverged": self.diverged,
            "packets": counts,
            "per_link": [{**d, "link": list(d["link"])} for d in self.counts.get("per_link", [])],
            "scenario_config": sc.to_dict(),
        }

    def save(self, out_dir, burn_in: int | None = None) -> Path:
        """Write ``run.npz`` (unless the save mode is ``summary``) and ``summary.json``.

        The folder is replaced as a whole and atomically (:func:`dkfsim.core.folders.staged`):
        no file of an earlier run survives beside the new ones.
        """
        summary = self.summary(burn_in)
        with staged(out_dir, "run") as tmp:
            if self.info.get("save") != "summary":
                np.savez(tmp / "run.npz", **self.arrays)
            write_json(tmp / "summary.json", summary)
        return Path(out_dir)

    def table(self, burn_in: int | None = None) -> str:
        """A short human-readable table: MSE per state component and packet counts."""
        m = self.metrics(burn_in)
        nx = self.arrays["truth"].shape[1]
        from dkfsim.config.schema import component_names
        names = component_names(self.scenario.model.kind, nx)
        rows = [("estimate", *names)]
        label = {"fused": "fused (%s)" % self.scenario.fusion, "local_mean": "local (mean over nodes)"}
        for key, val in m.items():
            if key == "burn_in":
                continue
            rows.append((label.get(key, key), *("%.4g" % v for v in val)))
        widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
        lines = [f"{self.scenario.name}: {self.scenario.steps} ticks, {len(self.scenario.sensors)} nodes, "
                 f"protocol {self.scenario.protocol}, L = {self.info['buffer_length']} "
                 f"(d_t = {self.info['d_t']}, d_g = {self.info['d_g']}), "
                 f"MSE after {m['burn_in']} burn-in rows"]
        for i, r in enumerate(rows):
            lines.append("  " + "  ".join(c.ljust(w) if j == 0 else c.rjust(w)
                                          for j, (c, w) in enumerate(zip(r, widths))))
            if i == 0:
                lines.append("  " + "  ".join("-" * w for w in widths))
        c = self.counts
        extra = "".join(f", {label} {c[key]}" for key, label in
                        (("copies", "duplicate copies"), ("crash_dropped", "dropped at crashed nodes"))
                        if c.get(key))
        lines.append(f"packets: sent {c['sent']}, delivered {c['delivered']}, lost {c['lost']}, "
                     f"in flight at end {c['in_flight']}{extra}; late contributions {c['late']}")
        if self.diverged:
            lines.append("DIVERGED: " + ", ".join(self.diverged) + " hold non-finite values (the "
                         "model or the numbers overflow float64); their MSE is inf or nan")
        lines.append(f"wall time {self.info['wall_time_s']:.2f} s")
        return "\n".join(lines)


#: Keys of summary.json that are facts of the run (``RunResult.info``).
INFO_KEYS = ("buffer_length", "d_t", "d_g", "n_links", "wall_time_s", "save")


def load_run(folder) -> RunResult:
    """Read a folder written by ``dkfsim run`` (or :meth:`RunResult.save`) back into a RunResult.

    The scenario is re-validated from the copy in ``summary.json`` (relative
    data files resolve against the original scenario file's folder); the
    arrays are those of ``run.npz`` (none when the run was saved with
    ``--save summary``).
    """
    import json

    from dkfsim.core.folders import from_json
    from dkfsim.config.schema import load_scenario
    from dkfsim.core.files import MAX_YAML_BYTES, check_regular_file, read_text
    folder = Path(folder)
    path = folder / "summary.json"
    try:
        summary = from_json(json.loads(read_text(path, limit=MAX_YAML_BYTES, what="summary.json")))
    except ValueError as exc:
        raise DkfsimError(f"{path}: not a summary written by dkfsim run ({exc})") from None
    if not isinstance(summary, dict) or "scenario_config" not in summary or "packets" not in summary:
        raise DkfsimError(f"{path}: not a summary written by dkfsim run (a Monte Carlo or maxdelay "
                          "folder? those are read by dkfsim plot)")
    source = summary.get("source")
    base = str(Path(source).resolve().parent) if source else None
    scenario = load_scenario(summary["scenario_config"], base_dir=base)
    scenario._source = source
    arrays: dict = {}
    npz = folder / "run.npz"
    if npz.exists():
        check_regular_file(npz, limit=1 << 40, what="run.npz")
        with np.load(npz, allow_pickle=False) as z:
            arrays = {key: z[key] for key in z.files}
    counts = dict(summary["packets"])
    counts["per_link"] = [{**d, "link": tuple(d["link"])} for d in summary.get("per_link", [])]
    info = {key: summary[key] for key in INFO_KEYS if key in summary}
    return RunResult(scenario, arrays, counts, info)

