"""Figures from the folders that ``dkfsim run`` and ``dkfsim montecarlo`` write.

``dkfsim plot DIR`` reads either layout and draws

* ``tracking``: truth, the fused estimate, node 0's estimate and the references
  (centralized Kalman filter; the consensus-on-information estimator when it
  ran), one panel per state component -- the paper's Fig. 3;
* ``mse``: mean squared error per tick and component for every estimate in the
  folder, log scale -- the paper's Fig. 4.  A Monte Carlo folder gives the mean
  over runs with its 95 % confidence band; a single run gives the squared error
  of that run, smoothed by a centred moving average (``--smooth``);
* ``nees`` (Monte Carlo folders only): the average NEES per tick with its 95 %
  consistency band.

``dkfsim plot DIR1 DIR2 ... --compare --labels ...`` overlays the fused MSE of
several folders and the centralized filter of the first -- the paper's Fig. 5
(undirected vs directed graph) and, on folders run with ``d_t = 0..4`` and
``--component position``, its Fig. 6.

Everything here is a function of the files on disk.  Problems a user can cause
(missing folder, a folder of neither layout, folders that cannot be overlaid)
raise :class:`~dkfsim.core.errors.DkfsimError`.  matplotlib is imported lazily with
the Agg backend, so the module imports on a machine without a display or
without matplotlib.
"""

from __future__ import annotations

import csv
import io
import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dkfsim.core.errors import DkfsimError
from dkfsim.config.schema import component_names as names_of
from dkfsim.core.encoding import from_json
from dkfsim.core.extras import available, optional, pyplot
from dkfsim.core.files import MAX_YAML_BYTES, read_text

FORMATS = ("png", "pdf", "svg")
DEFAULT_FORMATS = ("png", "pdf")

#: Display order, legend label and colour of the estimate names (any other name is drawn
#: after these, labelled by its name).
ESTIMATES: dict[str, tuple[str, str]] = {
    "fused": ("fused: anti-delay DKF", "C0"),
    "local": ("local: DKF node estimates (mean over nodes)", "C9"),
    "centralized": ("centralized: all data on time", "k"),
    "centralized_delayed": ("centralized_delayed: over delayed direct links", "C2"),
    "no_buffer": ("no_buffer: L = 1, fused", "C1"),
    "ci_consensus": ("ci_consensus: consensus on information", "C3"),
    "local_only": ("local_only: own sensor", "C7"),
}

#: Names folders written by earlier versions used (read as the current ones).
#: Estimate names of folders written before the one vocabulary (``algorithms`` in
#: Monte Carlo output), mapped to today's names.
OLD_NAMES = {"anti_delay_dkf": "fused", "anti_delay_dkf_local": "local", "local": "local_only"}
NOT_ESTIMATES = {"x_final", "x0_mean"}

CA_COMPONENTS = ("position", "velocity", "acceleration")
CA_UNITS = {"position": "m", "velocity": "m/s", "acceleration": "m/s$^2$"}


def label_of(name: str) -> str:
    return ESTIMATES.get(name, (name, None))[0]


def color_of(name: str, fallback_index: int = 0):
    c = ESTIMATES.get(name, (None, None))[1]
    return c if c is not None else f"C{(4 + fallback_index) % 10}"


def _order(names) -> list[str]:
    known = [a for a in ESTIMATES if a in names]
    return known + sorted(a for a in names if a not in ESTIMATES)


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


def component_names(nx: int, model_kind: str | None) -> list[str]:
    return names_of(model_kind, nx)


def _units(components, model_kind) -> list[str]:
    if model_kind in (None, "constant_acceleration") and list(components) == list(CA_COMPONENTS):
        return [CA_UNITS[c] for c in components]
    return [""] * len(components)


def _read_json(path: Path) -> dict:
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
    summary = _read_json(p / "summary.json") if (p / "summary.json").is_file() else {}
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
                  components=comps, units=_units(comps, kind), mse=mse, truth=truth,
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
    summary = _read_json(p / "summary.json") if (p / "summary.json").is_file() else {}
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
                  units=_units(comps, kind), mse=mse, ci=ci, truth=truth, examples=examples,
                  node0=node0, n_runs=n_runs or 0, d_t=_d_t(summary), nees=nees, nees_band=band,
                  burn_in=_int_or_none(summary.get("burn_in")), mse_ci95=ci95)


# ----------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------

def moving_average(a: np.ndarray, w: int) -> np.ndarray:
    """Centred moving average over ``w`` rows along axis 0; the window shrinks at the ends."""
    a = np.asarray(a, dtype=float)
    if w <= 1:
        return a
    K = a.shape[0]
    c = np.concatenate([np.zeros((1,) + a.shape[1:]), np.cumsum(a, axis=0)])
    lo = np.clip(np.arange(K) - w // 2, 0, K)
    hi = np.clip(np.arange(K) - w // 2 + w, 0, K)
    n = (hi - lo).reshape((K,) + (1,) * (a.ndim - 1))
    return (c[hi] - c[lo]) / n


def default_smooth(folder: Folder) -> int:
    """Single runs: 2 % of the ticks (the squared error of one run is very noisy); Monte Carlo: none."""
    return max(1, folder.K // 50) if folder.kind == "run" else 1


def select_components(folder: Folder, wanted) -> list[int]:
    """Indices of the components named (or numbered) in ``wanted``; all when empty."""
    if not wanted:
        return list(range(folder.nx))
    out = []
    for w in wanted:
        s = str(w)
        if s in folder.components:
            out.append(folder.components.index(s))
        elif s.isdigit() and int(s) < folder.nx:
            out.append(int(s))
        else:
            raise DkfsimError(f"--component: {s!r} is not a component of {folder.path} "
                              f"(components: {', '.join(folder.components)}, or 0..{folder.nx - 1})")
    return out


def _unit_label(unit: str, squared: bool = False) -> str:
    if not unit:
        return ""
    if squared:
        return f" [({unit})$^2$]" if "/" in unit or "$" in unit else f" [{unit}$^2$]"
    return f" [{unit}]"


def _mse_ylabel(folder: Folder, i: int, smooth: int) -> str:
    comp, unit = folder.components[i], folder.units[i]
    return f"{comp} MSE{_unit_label(unit, squared=True)}"


def mse_note(folder: Folder, smooth: int) -> str:
    if folder.kind == "montecarlo":
        note = f"mean over {folder.n_runs} Monte Carlo runs" if folder.n_runs else "mean over Monte Carlo runs"
        if folder.ci:
            note += ", 95 % CI shaded"
    else:
        note = "single run: squared error"
    if smooth > 1:
        note += f", {smooth}-tick moving average"
    return note


def _save_png(fig, path: Path, dpi: int = 100) -> None:
    """PNG with a 256-colour palette: a third of the size of matplotlib's RGBA, same look."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    if available("PIL"):
        Image = optional("PIL.Image")
        img = Image.open(buf).convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT)
        img.save(path, format="PNG", optimize=True)
    else:                 # Pillow ships with matplotlib; keep the plain file if it is missing
        Path(path).write_bytes(buf.getvalue())


def _save(fig, stem: Path, formats) -> list[Path]:
    stem = Path(stem)
    try:
        stem.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DkfsimError(f"{stem.parent}: cannot create the figure folder ({exc.strerror})") from None
    out = []
    for fmt in formats:
        path = stem.with_name(f"{stem.name}.{fmt}")
        tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
        try:                       # written beside, then renamed: never half a figure
            if fmt == "png":
                _save_png(fig, tmp)
            else:
                fig.savefig(tmp, bbox_inches="tight", format=fmt)
            os.replace(tmp, path)
        except OSError as exc:
            raise DkfsimError(f"{path}: cannot write the figure ({exc.strerror})") from None
        finally:
            tmp.unlink(missing_ok=True)
        out.append(path)
    fig.clf()
    pyplot().close(fig)
    return out


def _averages(ax, entries, folder: Folder) -> None:
    """A column right of the panel: each curve's time-averaged MSE after the burn-in, in its colour
    (with the 95 % interval over runs when the Monte Carlo summary has it)."""
    b = folder.burn_in if folder.burn_in is not None else folder.K // 10
    ax.text(1.02, 1.0, f"MSE, mean\nover t ≥ {folder.t[min(b, folder.K - 1)]:g} s:", transform=ax.transAxes,
            ha="left", va="top", fontsize=7.5, color="0.3")
    for j, (text, col) in enumerate(entries):
        ax.text(1.02, 0.80 - 0.105 * j, text, transform=ax.transAxes, ha="left", va="top",
                fontsize=7.5, color=col, fontweight="bold")


def _avg_text(folder: Folder, estimate: str, i: int) -> str:
    m = folder.time_average(estimate, i)
    ci = folder.ci95(estimate, i)
    return f"{m:.4g}" if ci is None else f"{m:.4g} ± {(ci[1] - ci[0]) / 2:.2g}"


def _legend_below(fig, ax, ncol=2):
    """One legend for all panels, under them, so that it never hides a curve."""
    handles, labels = ax.get_legend_handles_labels()
    fig.tight_layout()
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=ncol,
               fontsize=8.5, frameon=False)


def _check_formats(formats) -> tuple[str, ...]:
    formats = tuple(formats)
    if not formats:
        raise DkfsimError("--format: give at least one format")
    for f in formats:
        if f not in FORMATS:
            raise DkfsimError(f"--format: unknown format {f!r}; choose from {', '.join(FORMATS)}")
    return formats


def _positive(a):
    """Zeros (exact estimates) cannot be drawn on a log axis; mask them."""
    a = np.asarray(a, dtype=float)
    return np.where(a > 0, a, np.nan)


def _band(lo, hi):
    """A confidence band for a log axis: a lower bound <= 0 (t-interval of few runs) goes to the floor."""
    lo = np.asarray(lo, dtype=float)
    return np.where(lo > 0, lo, 1e-300), _positive(hi)


def _plain_log_ticks(ax) -> None:
    """Tick labels 0.2, 0.05, 1e-05 instead of 2 x 10^-1 (matplotlib decides which ticks get one)."""
    class Plain(optional("matplotlib.ticker").LogFormatter):
        def __call__(self, x, pos=None):
            return f"{x:g}" if super().__call__(x, pos) else ""

    ax.yaxis.set_major_formatter(Plain(labelOnlyBase=False))
    ax.yaxis.set_minor_formatter(Plain(labelOnlyBase=False))


def _log_limits(ax, curves) -> None:
    """Fit the log axis to the mean curves (not to the bands, whose lower ends can be ~0)."""
    _plain_log_ticks(ax)
    vals = np.concatenate([np.asarray(c, dtype=float).ravel() for c in curves])
    vals = vals[np.isfinite(vals) & (vals > 0)]
    if vals.size:
        ax.set_ylim(np.percentile(vals, 0.5) / 2.0, vals.max() * 2.0)


# ----------------------------------------------------------------------------
# figures
# ----------------------------------------------------------------------------

def zoom_window(K: int) -> tuple[int, int]:
    """Rows shown in the zoom column of the tracking figure: 8 % of the run, centred."""
    n = max(2, min(K, round(0.08 * K)))
    lo = max(0, K // 2 - n // 2)
    return lo, min(K, lo + n)


def plot_tracking(folder: Folder, stem, formats=DEFAULT_FORMATS, components=None, title=None,
                  zoom=True) -> list[Path]:
    """Truth, fused, node 0 and the references, one row per component (paper Fig. 3).

    The left column shows the whole run; at that scale every estimate lies on
    the truth, so the right column repeats a short window (shaded on the left)
    where the estimates can be told apart.
    """
    formats = _check_formats(formats)
    if folder.truth is None:
        raise DkfsimError(f"{folder.path}: no example run (example_truth) to draw the tracking figure from")
    idx = select_components(folder, components)
    plt = pyplot()
    ncols = 2 if zoom and folder.K >= 20 else 1
    fig, axes = plt.subplots(len(idx), ncols, figsize=(9.0 if ncols == 2 else 7.5, 2.3 * len(idx) + 0.6),
                             sharex="col", squeeze=False,
                             gridspec_kw={"width_ratios": [2.2, 1]} if ncols == 2 else None)
    t = folder.t
    lines = [("truth", folder.truth, dict(color="0.6", lw=3.0, zorder=1))]
    if "fused" in folder.examples:
        lines.append((label_of("fused"), folder.examples["fused"],
                      dict(color=color_of("fused"), lw=1.2, zorder=4)))
    if folder.node0 is not None:
        lines.append(("anti-delay DKF, node 0 (real time)", folder.node0,
                      dict(color="C4", lw=1.0, ls=(0, (1.5, 1.2)), zorder=3)))
    if "centralized" in folder.examples:
        lines.append((label_of("centralized"), folder.examples["centralized"],
                      dict(color="k", lw=0.9, ls="--", zorder=5)))
    if "ci_consensus" in folder.examples:
        lab = label_of("ci_consensus") + (", node 0" if folder.kind == "run" else "")
        lines.append((lab, folder.examples["ci_consensus"],
                      dict(color=color_of("ci_consensus"), lw=1.0, ls="-.", zorder=2)))
    lo, hi = zoom_window(folder.K)
    for row, i in enumerate(idx):
        ax = axes[row, 0]
        for lab, x, style in lines:
            ax.plot(t, x[:, i], label=lab, **style)
        ax.set_ylabel(folder.components[i] + _unit_label(folder.units[i]))
        ax.grid(True, alpha=0.3)
        ax.margins(x=0)
        if ncols == 2:
            ax.axvspan(t[lo], t[hi - 1], color="C1", alpha=0.15, lw=0)
            az = axes[row, 1]
            for lab, x, style in lines:
                az.plot(t[lo:hi], x[lo:hi, i], **style)
            az.grid(True, alpha=0.3)
            az.margins(x=0)
            az.set_facecolor((1.0, 0.97, 0.93))
    axes[-1, 0].set_xlabel("time [s]")
    if ncols == 2:
        axes[-1, 1].set_xlabel("time [s] (zoom)")
        axes[0, 1].set_title("zoom on the shaded window", fontsize=9)
    sub = "" if folder.kind == "run" else " (one example run)"
    fig.suptitle(title or f"Tracking: {folder.describe()}{sub}", fontsize=11)
    _legend_below(fig, axes[0, 0], ncol=3 if len(lines) > 4 else 2)
    return _save(fig, stem, formats)


def plot_mse(folder: Folder, stem, formats=DEFAULT_FORMATS, components=None, smooth=None,
             estimates=None, title=None) -> list[Path]:
    """MSE per tick and component for every estimate in the folder (paper Fig. 4)."""
    formats = _check_formats(formats)
    idx = select_components(folder, components)
    w = default_smooth(folder) if smooth is None else max(1, int(smooth))
    names = _order(folder.mse) if estimates is None else [a for a in estimates if a in folder.mse]
    if not names:
        raise DkfsimError(f"{folder.path}: none of the estimates {', '.join(estimates or [])} is in the folder")
    plt = pyplot()
    fig, axes = plt.subplots(len(idx), 1, figsize=(7.5, 2.3 * len(idx) + 0.9), sharex=True, squeeze=False)
    for ax, i in zip(axes[:, 0], idx):
        drawn, entries = [], []
        for j, a in enumerate(names):
            col = color_of(a, j)
            entries.append((_avg_text(folder, a, i), col))
            style = dict(color=col, lw=1.0, ls="--" if a == "centralized" else "-",
                         zorder={"fused": 5, "centralized": 6}.get(a, 3))
            y = _positive(moving_average(folder.mse[a][:, i], w))
            drawn.append(y)
            ax.plot(folder.t, y, label=label_of(a), **style)
            if a in folder.ci:
                lo, hi = folder.ci[a]
                ax.fill_between(folder.t, *_band(moving_average(lo[:, i], w), moving_average(hi[:, i], w)),
                                color=col, alpha=0.2, lw=0)
        ax.set_yscale("log")
        _log_limits(ax, drawn)
        _averages(ax, entries, folder)
        ax.set_ylabel(_mse_ylabel(folder, i, w))
        ax.grid(True, which="both", alpha=0.25)
        ax.margins(x=0)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle((title or f"MSE per tick: {folder.describe()}") + f"\n({mse_note(folder, w)})", fontsize=11)
    _legend_below(fig, axes[0, 0])
    return _save(fig, stem, formats)


def plot_nees(folder: Folder, stem, formats=DEFAULT_FORMATS, title=None) -> list[Path]:
    """Average NEES per tick with its 95 % consistency band (Monte Carlo folders)."""
    formats = _check_formats(formats)
    if not folder.nees:
        raise DkfsimError(f"{folder.path}: no NEES curves")
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 3.4))
    for j, a in enumerate(_order(folder.nees)):
        if np.all(~np.isfinite(folder.nees[a])):
            continue
        ax.plot(folder.t, folder.nees[a], color=color_of(a, j), lw=1.0, label=label_of(a),
                ls="--" if a == "centralized" else "-")
    if folder.nees_band is not None:
        ax.axhspan(*folder.nees_band, color="0.5", alpha=0.18, lw=0, label="95 % consistency band")
    ax.axhline(folder.nx, color="0.3", lw=0.8, ls=":")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("average NEES")
    ax.grid(True, alpha=0.3)
    ax.margins(x=0)
    n = f"{folder.n_runs} runs" if folder.n_runs else "Monte Carlo runs"
    ax.set_title(title or f"Consistency: {folder.describe()} (mean NEES over {n}; expected value {folder.nx})",
                 fontsize=10)
    _legend_below(fig, ax)
    return _save(fig, stem, formats)


def check_comparable(folders: list[Folder]) -> None:
    first = folders[0]
    for f in folders[1:]:
        if f.K != first.K:
            raise DkfsimError(f"--compare: {f.path} has {f.K} ticks but {first.path} has {first.K}; "
                              f"compare folders run with the same number of steps")
        if not np.allclose(f.t, first.t, rtol=1e-9, atol=0):
            raise DkfsimError(f"--compare: {f.path} and {first.path} have different sample times "
                              f"(sampling periods {f.t[0]:g} s and {first.t[0]:g} s)")
        if f.components != first.components:
            raise DkfsimError(f"--compare: {f.path} has components {', '.join(f.components)} but "
                              f"{first.path} has {', '.join(first.components)}")


def plot_compare(folders: list[Folder], stem, labels=None, formats=DEFAULT_FORMATS, components=None,
                 smooth=None, title=None, estimate="fused", bands=None,
                 relative=False) -> list[Path]:
    """Fused MSE of several folders and the centralized filter of the first (paper Figs. 5, 6).

    ``relative`` adds a right-hand column with each folder's MSE divided by the
    first folder's centralized MSE (both moving-averaged over 5 % of the run):
    on the same draws the noise common to all curves cancels, so differences
    of a few per cent, invisible on the log scale, show.
    """
    formats = _check_formats(formats)
    if len(folders) < 2:
        raise DkfsimError("--compare: give at least two folders")
    if labels is None:
        labels = [f.path.name or str(f.path) for f in folders]
    labels = list(labels)
    if len(labels) != len(folders):
        raise DkfsimError(f"--labels: {len(labels)} labels for {len(folders)} folders; give one label per folder")
    check_comparable(folders)
    for f in folders:
        if estimate not in f.mse:
            raise DkfsimError(f"--compare: {f.path} has no {label_of(estimate)} estimate")
    first = folders[0]
    if relative and "centralized" not in first.mse:
        raise DkfsimError(f"--relative: the first folder ({first.path}) has no centralized estimate "
                          f"to divide by; run it with estimators including {{kind: centralized}}")
    idx = select_components(first, components)
    w = default_smooth(first) if smooth is None else max(1, int(smooth))
    if smooth is None and any(f.kind == "run" for f in folders):
        w = max(default_smooth(f) for f in folders)
    wr = max(w, first.K // 20)
    plt = pyplot()
    ncols = 2 if relative else 1
    height = 2.3 * len(idx) + 1.0 if len(idx) > 1 else 3.8
    fig, axes = plt.subplots(len(idx), ncols, figsize=(12.0 if relative else 7.5, height),
                             sharex=True, squeeze=False,
                             gridspec_kw={"width_ratios": [1.25, 1]} if relative else None)
    n = len(folders)
    cmap = plt.get_cmap("viridis")
    colors = [f"C{j}" for j in range(n)] if n <= 3 else [cmap(0.9 * j / (n - 1)) for j in range(n)]
    if bands is None:      # overlapping per-tick bands of many curves hide the curves
        bands = n <= 2
    for row, i in enumerate(idx):
        ax = axes[row, 0]
        drawn, entries = [], []
        for f, lab, col in zip(folders, labels, colors):
            y = _positive(moving_average(f.mse[estimate][:, i], w))
            drawn.append(y)
            entries.append((_avg_text(f, estimate, i), col))
            ax.plot(f.t, y, color=col, lw=1.1, label=lab)
            if bands and estimate in f.ci:
                lo, hi = f.ci[estimate]
                ax.fill_between(f.t, *_band(moving_average(lo[:, i], w), moving_average(hi[:, i], w)),
                                color=col, alpha=0.18, lw=0)
        if "centralized" in first.mse:
            y = _positive(moving_average(first.mse["centralized"][:, i], w))
            drawn.append(y)
            entries.append((_avg_text(first, "centralized", i), "k"))
            ax.plot(first.t, y, color="k", lw=1.0, ls="--",
                    label="centralized KF (all data on time)" + (f", from {labels[0]}" if len(labels[0]) < 12 else ""))
        ax.set_yscale("log")
        _log_limits(ax, drawn)
        ax.set_ylabel(_mse_ylabel(first, i, w))
        ax.grid(True, which="both", alpha=0.25)
        ax.margins(x=0)
        if relative:
            ar = axes[row, 1]
            den = moving_average(first.mse["centralized"][:, i], wr)
            for f, col in zip(folders, colors):
                ar.plot(f.t, moving_average(f.mse[estimate][:, i], wr) / den, color=col, lw=1.2)
            ar.axhline(1.0, color="k", lw=1.0, ls="--")
            ar.set_ylabel(f"{first.components[i]} MSE / centralized")
            ar.grid(True, alpha=0.3)
            ar.margins(x=0)
            if row == 0:
                ar.set_title(f"relative to the centralized KF ({wr}-tick moving averages)", fontsize=9)
        _averages(axes[row, -1], entries, first)
    for c in range(ncols):
        axes[-1, c].set_xlabel("time [s]")
    kinds = {f.kind for f in folders}
    ref = folders[0]
    note = mse_note(ref if kinds == {ref.kind} else next(f for f in folders if f.kind == "run"), w)
    if not bands and any(f.ci for f in folders):
        note = note.replace(", 95 % CI shaded", "")
    what = "fused anti-delay DKF" if estimate == "fused" else label_of(estimate)
    fig.suptitle((title or f"MSE of the {what}: " + ", ".join(labels)) + f"\n({note})", fontsize=11)
    _legend_below(fig, axes[0, 0], ncol=3 if n + 1 > 4 else 2)
    return _save(fig, stem, formats)


def plot_folder(folder: Folder, out_dir, formats=DEFAULT_FORMATS, components=None, smooth=None) -> list[Path]:
    """Every figure a single folder supports, into ``out_dir``."""
    out = Path(out_dir)
    written = []
    if folder.truth is not None:
        written += plot_tracking(folder, out / "tracking", formats, components)
    written += plot_mse(folder, out / "mse", formats, components, smooth)
    if folder.nees:
        written += plot_nees(folder, out / "nees", formats)
    return written


# ----------------------------------------------------------------------------
# command line
# ----------------------------------------------------------------------------
