"""What a run returns and writes (DESIGN.md section 5).

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

from .errors import DkfsimError
from .metrics import default_burn_in, run_metrics
from .output import staged, write_json

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

    from . import __version__
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
        return run_metrics(self.arrays, default_burn_in(K) if burn_in is None else burn_in)

    def summary(self, burn_in: int | None = None) -> dict:
        from .scenario import scenario_hash
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
            "packets": counts,
            "per_link": [{**d, "link": list(d["link"])} for d in self.counts.get("per_link", [])],
            "scenario_config": sc.to_dict(),
        }

    def save(self, out_dir, burn_in: int | None = None) -> Path:
        """Write ``run.npz`` (unless the save mode is ``summary``) and ``summary.json``.

        The folder is replaced as a whole and atomically (:func:`dkfsim.output.staged`):
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
        from .scenario import component_names
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
        lines.append(f"wall time {self.info['wall_time_s']:.2f} s")
        return "\n".join(lines)
