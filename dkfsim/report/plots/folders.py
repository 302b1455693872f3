"""Reading the folders ``dkfsim run`` and ``dkfsim montecarlo`` write into one :class:`Folder`.

Either layout (a single run's ``estimates.npz`` or a Monte Carlo ``curves.npz`` and
``summary.json``) gives what the figures need; old estimate names are read as today's.
See :mod:`dkfsim.report.plots` and docs/design.md.
"""

from __future__ import annotations

import csv
import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dkfsim.config.dynamics import CA_UNITS
from dkfsim.config.dynamics import component_names as names_of
from dkfsim.core.encoding import from_json
from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import MAX_YAML_BYTES, read_text

#: Names folders written by earlier versions used (read as the current ones).
#: Estimate names of folders written before the one vocabulary (``algorithms`` in
#: Monte Carlo output), mapped to today's names.
OLD_NAMES = {"anti_delay_dkf": "fused", "anti_delay_dkf_local": "local", "local": "local_only"}
NOT_ESTIMATES = {"x_final", "x0_mean"}

CA_COMPONENTS = ("position", "velocity", "acceleration")



# ----------------------------------------------------------------------------
# reading folders
# ----------------------------------------------------------------------------

@dataclass
class Folder:
    """What the figures need from one folder, whatever its layout."""

    path: Path
    kind: str                         # "run" | "montecarlo"
    scenario: str
    t: np.ndarray                     # (K,)
    components: list[str]
    units: list[str]                  # "" when the model has no physical units
    mse: dict[str, np.ndarray]        # estimate -> (K, nx): squared error per tick (mean over runs)
    ci: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    truth: np.ndarray | None = None   # (K, nx), one example run
    examples: dict[str, np.ndarray] = field(default_factory=dict)   # estimate -> (K, nx)
    node0: np.ndarray | None = None   # (K, nx)
    n_runs: int = 1
    d_t: int | None = None
    nees: dict[str, np.ndarray] = field(default_factory=dict)       # estimate -> (K,)
    nees_band: tuple[float, float] | None = None
    burn_in: int | None = None        # rows skipped in the time averages (default: 10 % of K)
    mse_ci95: dict[str, list] = field(default_factory=dict)   # estimate -> per component [lo, hi]

    def time_average(self, estimate: str, i: int) -> float:
        """MSE of one component averaged over the ticks after the burn-in."""
        b = self.burn_in if self.burn_in is not None and 0 <= self.burn_in < self.K else self.K // 10
        return float(np.mean(self.mse[estimate][b:, i]))

    def ci95(self, estimate: str, i: int) -> tuple[float, float] | None:
        """95 % interval of the time-averaged MSE over runs (Monte Carlo summary.json), if known."""
        try:
            v = self.mse_ci95[estimate]
            lo, hi = v[self.components[i]] if isinstance(v, dict) else v[i]
            return (float(lo), float(hi)) if lo is not None and hi is not None else None
        except (KeyError, IndexError, TypeError, ValueError):
            return None

    @property
    def K(self) -> int:
        return int(self.t.shape[0])

    @property
    def nx(self) -> int:
        return len(self.components)

    def describe(self) -> str:
        s = self.scenario
        if self.d_t is not None:
            s += f", $d_t$ = {self.d_t}"
        return s

    def condition(self) -> str:
        """What a figure title says about the folder: its conditions (``d_t``), never a
        file or folder name (figures go into papers; decisions in docs/decisions.md)."""
        return f"$d_t$ = {self.d_t}" if self.d_t is not None else ""


def component_names(nx: int, model_kind: str | None) -> list[str]:
    return names_of(model_kind, nx)


def component_units(components, model_kind) -> list[str]:
    if model_kind in (None, "constant_acceleration") and list(components) == list(CA_COMPONENTS):
        return [CA_UNITS[c] for c in components]
    return [""] * len(components)


def read_json_file(path: Path) -> dict:
    try:
        data = from_json(json.loads(read_text(path, limit=MAX_YAML_BYTES, what="JSON file")))
    except ValueError as exc:
        raise DkfsimError(f"{path}: cannot read ({exc})") from None
    if not isinstance(data, dict):
        raise DkfsimError(f"{path}: expected a JSON object")
    return data


def _read_npz(path: Path) -> dict:
    """All arrays of an npz file; object arrays (e.g. string lists) are read too."""
    out = {}
    try:
        with np.load(path, allow_pickle=False) as z:
            names = list(z.files)
            pickled = []
            for k in names:
                try:
                    out[k] = z[k]
                except ValueError:
                    pickled.append(k)
        if pickled:
            # Our own files may store string lists as object arrays.
            with np.load(path, allow_pickle=True) as z:
                for k in pickled:
                    out[k] = z[k]
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise DkfsimError(f"{path}: not a readable .npz file ({exc})") from None
    return out


def _model_kind(summary: dict) -> str | None:
    cfg = summary.get("scenario_config")
    if isinstance(cfg, dict) and isinstance(cfg.get("model"), dict):
        return cfg["model"].get("kind")
    return None


def _d_t(summary: dict) -> int | None:
    val = summary.get("d_t")
    if val is None:
        try:
            val = summary["scenario_config"]["links"]["default"]["latency"]["d_t"]
        except (KeyError, TypeError):
            return None
    try:
        return int(val)
    except (TypeError, ValueError):
        return None


def _int_or_none(v) -> int | None:
    return v if isinstance(v, int) and not isinstance(v, bool) else None


def _need(arrays: dict, key: str, path: Path, shape=None):
    if key not in arrays:
        raise DkfsimError(f"{path}: no array {key!r}")
    a = np.asarray(arrays[key])
    if shape is not None:
        ok = a.ndim == len(shape) and all(s is None or s == d for s, d in zip(shape, a.shape))
        if not ok:
            want = "(" + ", ".join("?" if s is None else str(s) for s in shape) + ")"
            raise DkfsimError(f"{path}: array {key!r} has shape {a.shape}, expected {want}")
    return a


def load_folder(path) -> Folder:
    """Read a ``dkfsim run`` folder or a ``dkfsim montecarlo`` folder."""
    p = Path(path)
    if not p.exists():
        raise DkfsimError(f"{path}: no such folder")
    if not p.is_dir():
        raise DkfsimError(f"{path}: not a folder (give the folder that dkfsim run or "
                          f"dkfsim montecarlo wrote, not a file in it)")
    if (p / "run.npz").is_file():
        return _load_run(p)
    if (p / "curves.npz").is_file():
        return _load_montecarlo(p)
    if (p / "summary.json").is_file() and (p / "runs.csv").is_file():
        raise DkfsimError(f"{path}: Monte Carlo folder without curves.npz; nothing to plot")
    if (p / "summary.json").is_file():
        raise DkfsimError(f"{path}: has summary.json but no run.npz (was it run with --save summary?); "
                          f"rerun with --save estimates to plot it")
    raise DkfsimError(f"{path}: neither a run folder (run.npz + summary.json, written by dkfsim run) "
                      f"nor a Monte Carlo folder (curves.npz + summary.json, written by dkfsim montecarlo)")


def _load_run(p: Path) -> Folder:
    arrays = _read_npz(p / "run.npz")
    summary = read_json_file(p / "summary.json") if (p / "summary.json").is_file() else {}
    truth = _need(arrays, "truth", p / "run.npz", (None, None))
    K, nx = truth.shape
    t = _need(arrays, "t", p / "run.npz", (K,)).astype(float)
    kind = _model_kind(summary)
    comps = component_names(nx, kind)
    mse, examples = {}, {}
    node0 = None
    keys = [k for k in arrays if k.startswith("x_") and k not in NOT_ESTIMATES]
    for key in keys:
        x = np.asarray(arrays[key], dtype=float)
        name = key[2:]
        if x.ndim == 2 and x.shape == (K, nx):
            err = (x - truth) ** 2
            examples[name] = x
        elif x.ndim == 3 and x.shape[0] == K and x.shape[2] == nx:
            err = np.mean((x - truth[:, None, :]) ** 2, axis=1)
            examples[name] = x[:, 0, :]          # node 0
            if key == "x_local":
                node0 = x[:, 0, :]
        else:
            raise DkfsimError(f"{p / 'run.npz'}: array {key!r} has shape {x.shape}, "
                              f"expected ({K}, {nx}) or ({K}, n, {nx})")
        mse[name] = err
    if "fused" not in mse and "local" not in mse:
        raise DkfsimError(f"{p / 'run.npz'}: no estimates (x_fused or x_local) to plot")
    return Folder(path=p, kind="run", scenario=str(summary.get("scenario", p.name)), t=t,
                  components=comps, units=component_units(comps, kind), mse=mse, truth=truth,
                  examples=examples, node0=node0, n_runs=1, d_t=_d_t(summary),
                  burn_in=_int_or_none((summary.get("metrics") or {}).get("burn_in")))


def _count_runs(p: Path) -> int | None:
    f = p / "runs.csv"
    if not f.is_file():
        return None
    try:
        with open(f, newline="") as fh:
            return len({row.get("run") for row in csv.DictReader(fh)}) or None
    except (OSError, csv.Error):
        return None


def _load_montecarlo(p: Path) -> Folder:
    f = p / "curves.npz"
    arrays = _read_npz(f)
    summary = read_json_file(p / "summary.json") if (p / "summary.json").is_file() else {}
    t = _need(arrays, "t", f, (None,)).astype(float)
    K = t.shape[0]
    comps = [str(c) for c in _need(arrays, "components", f, (None,))]
    nx = len(comps)
    key = "estimates" if "estimates" in arrays else "algorithms"      # (older folders)
    algs = [OLD_NAMES.get(str(a), str(a)) if key == "algorithms" else str(a)
            for a in _need(arrays, key, f, (None,))]
    A = len(algs)
    mse_all = _need(arrays, "mse", f, (A, K, nx)).astype(float)
    mse = {a: mse_all[i] for i, a in enumerate(algs)}
    ci = {}
    if "mse_ci_lo" in arrays and "mse_ci_hi" in arrays:
        lo = _need(arrays, "mse_ci_lo", f, (A, K, nx)).astype(float)
        hi = _need(arrays, "mse_ci_hi", f, (A, K, nx)).astype(float)
        ci = {a: (lo[i], hi[i]) for i, a in enumerate(algs)}
    examples, truth, node0 = {}, None, None
    if "example_truth" in arrays:
        truth = _need(arrays, "example_truth", f, (K, nx)).astype(float)
        if "example_x" in arrays:
            ex = _need(arrays, "example_x", f, (A, K, nx)).astype(float)
            examples = {a: ex[i] for i, a in enumerate(algs)}
        if "example_node0" in arrays:
            node0 = _need(arrays, "example_node0", f, (K, nx)).astype(float)
    nees, band = {}, None
    if "nees" in arrays:
        ne = _need(arrays, "nees", f, (A, K)).astype(float)
        nees = {a: ne[i] for i, a in enumerate(algs)}
        if "nees_band" in arrays:
            b = _need(arrays, "nees_band", f, (2,)).astype(float)
            band = (float(b[0]), float(b[1]))
    kind = _model_kind(summary)
    n_runs = _count_runs(p)
    if n_runs is None:
        for key in ("runs", "n_runs"):
            if isinstance(summary.get(key), int):
                n_runs = summary[key]
                break
    name = summary.get("scenario", p.name)
    if isinstance(name, dict):
        name = name.get("name", p.name)
    ci95 = {}
    per_estimate = summary.get("estimates", summary.get("algorithms"))
    if isinstance(per_estimate, dict):
        ci95 = {OLD_NAMES.get(a, a) if "algorithms" in summary else a: v["mse_ci95"]
                for a, v in per_estimate.items() if isinstance(v, dict) and "mse_ci95" in v}
    return Folder(path=p, kind="montecarlo", scenario=str(name), t=t, components=comps,
                  units=component_units(comps, kind), mse=mse, ci=ci, truth=truth, examples=examples,
                  node0=node0, n_runs=n_runs or 0, d_t=_d_t(summary), nees=nees, nees_band=band,
                  burn_in=_int_or_none(summary.get("burn_in")), mse_ci95=ci95)

