"""Reading the folders ``dkfsim run`` and ``dkfsim montecarlo`` write into one :class:`Folder`.

Either layout (a single run's ``estimates.npz`` or a Monte Carlo ``curves.npz`` and
``summary.json``) gives what the figures need; old estimate names are read as today's.
See :mod:`dkfsim.report.plots` and docs/design.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dkfsim.components.mobility import link_pairs, link_uptime
from dkfsim.config.dynamics import component_names as names_of
from dkfsim.config.dynamics import component_units
from dkfsim.config.load import stored_scenario
from dkfsim.config.plan import RunPlan
from dkfsim.config.results import (
    NAME_LIMIT,
    MonteCarloSummary,
    RunSummary,
    npz_header,
    read_curves,
    read_record,
    read_run_seeds,
)
from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import clip
from dkfsim.core.npzfile import NpzFile

NOT_ESTIMATES = {"x_final", "x0_mean"}

#: A rate-limited run's per-link arrays beside ``rated_links`` (E, 2), with their shapes.
LINK_ARRAYS = {"queue_length": ("K", "E"), "utilisation": ("K", "E"), "queueing_delay_quantiles": ("E", 101)}

#: A run with ``mobility:``: its arrays beside ``mobility_links`` (E, 2), with their shapes
#: (``n`` the scenario's nodes); summary.json's ``mobility.link_uptime`` has one row per pair.
MOBILITY_ARRAYS = {"positions": ("K", "n", 2), "links_up": ("K", "E")}


#: A run on a spatial radio (``medium.radio``): each member's CBR per tick and the members.
RADIO_ARRAYS = {"cbr": ("K", "M"), "cbr_nodes": ("M",)}


class NothingToPlot(DkfsimError):
    """A folder dkfsim wrote without arrays to draw (``--save summary``): not a damaged one."""



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
    #: estimate -> its summary.json entry (Monte Carlo): anees, anees_ci95, anees_consistent, paired
    stats: dict[str, dict] = field(default_factory=dict)
    #: a rate-limited run's links (run.npz): ``rated_links`` (E, 2), ``queue_length`` and
    #: ``utilisation`` (K, E), ``queueing_delay_quantiles`` (E, 101); empty otherwise
    links: dict[str, np.ndarray] = field(default_factory=dict)
    #: a run with ``mobility:`` (run.npz): ``mobility_links`` (E, 2), ``positions`` (K, n, 2),
    #: ``links_up`` (K, E) and ``link_uptime`` (E,) from summary.json; a Monte Carlo folder of
    #: such a scenario: the same, replayed from its stored scenario (:func:`_replayed_mobility`);
    #: empty otherwise
    mobility: dict[str, np.ndarray] = field(default_factory=dict)
    #: a run on a spatial radio: ``cbr`` (K, M) and ``cbr_nodes`` (M,) from run.npz, and the DKF's
    #: ``pdr_by_distance`` block from summary.json (``pdr``: None where no pair fell); empty otherwise
    radio: dict = field(default_factory=dict)

    def fraction_in_band(self, estimate: str) -> float | None:
        """Fraction of the ticks after the burn-in whose mean NEES lies in the per-tick band."""
        if self.nees_band is None or estimate not in self.nees:
            return None
        m = self.nees[estimate][self.burn_rows():]
        m = m[np.isfinite(m)]
        if m.size == 0:
            return None
        return float(np.mean((m >= self.nees_band[0]) & (m <= self.nees_band[1])))

    def burn_rows(self) -> int:
        """Rows skipped in the time averages: ``burn_in``, else 10 % of the ticks."""
        return self.burn_in if self.burn_in is not None and 0 <= self.burn_in < self.K else self.K // 10

    def time_average(self, estimate: str, i: int) -> float:
        """MSE of one component averaged over the ticks after the burn-in."""
        return float(np.mean(self.mse[estimate][self.burn_rows():, i]))

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


def _model_kind(summary: dict) -> str | None:
    cfg = summary.get("scenario_config")
    if isinstance(cfg, dict) and isinstance(cfg.get("model"), dict):
        kind = cfg["model"].get("kind")
        return kind if isinstance(kind, str) else None
    return None


def _d_t(summary: dict) -> int | None:
    val = summary.get("d_t")
    if val is None:
        try:
            val = summary["scenario_config"]["links"]["default"]["latency"]["d_t"]
        except (KeyError, TypeError):
            return None
    return val if isinstance(val, int) and not isinstance(val, bool) else None


# ----------------------------------------------------------------------------
# arrays: every header checked before any data is read
# ----------------------------------------------------------------------------

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
        raise NothingToPlot(f"{path}: Monte Carlo folder without curves.npz; nothing to plot")
    if (p / "summary.json").is_file():
        raise NothingToPlot(f"{path}: has summary.json but no run.npz (was it run with --save summary?); "
                            f"rerun with --save estimates to plot it")
    raise DkfsimError(f"{path}: neither a run folder (run.npz + summary.json, written by dkfsim run) "
                      f"nor a Monte Carlo folder (curves.npz + summary.json, written by dkfsim montecarlo)")


def _load_run(p: Path) -> Folder:
    f = p / "run.npz"
    summary = read_record(p / "summary.json", RunSummary, "summary.json") \
        if (p / "summary.json").is_file() else {}
    with NpzFile(f, "run.npz") as z:
        truth = npz_header(z, "truth", (summary.get("steps"), None))
        K, nx = truth.shape
        npz_header(z, "t", (K,))
        keys = [k for k in z.files if k.startswith("x_") and k not in NOT_ESTIMATES]
        for key in keys:
            h = npz_header(z, key)
            if not (h.shape == (K, nx) or (len(h.shape) == 3 and h.shape[0] == K and h.shape[2] == nx)):
                raise DkfsimError(f"{f}: array {clip(key)} has shape {h.shape}, expected ({K}, {nx}) "
                                  f"or ({K}, n, {nx})")
            if len(key) - 2 > NAME_LIMIT:
                raise DkfsimError(f"{f}: array name {clip(key)} is longer than {NAME_LIMIT} characters")
        link_keys = []
        if "rated_links" in z:
            E = npz_header(z, "rated_links", (None, 2)).shape[0]
            for key, shape in LINK_ARRAYS.items():
                npz_header(z, key, _dims(shape, K=K, E=E))
            link_keys = ["rated_links", *LINK_ARRAYS]
        mobility_keys = _check_mobility(z, summary, K)
        radio_keys = []
        if "cbr" in z or "cbr_nodes" in z:
            M = npz_header(z, "cbr_nodes", (None,)).shape[0]
            npz_header(z, "cbr", (K, M))
            radio_keys = list(RADIO_ARRAYS)
        arrays = z.read(["t", "truth", *keys, *link_keys, *mobility_keys, *radio_keys])
    truth = arrays["truth"].astype(float)
    t = arrays["t"].astype(float)
    kind = _model_kind(summary)
    comps = component_names(nx, kind)
    mse, examples = {}, {}
    node0 = None
    with np.errstate(all="ignore"):           # a diverged estimate's error is inf / nan: drawn as such
        for key in keys:
            x = np.asarray(arrays[key], dtype=float)
            name = key[2:]
            if x.ndim == 2:
                err = (x - truth) ** 2
                examples[name] = x
            else:
                err = np.mean((x - truth[:, None, :]) ** 2, axis=1)
                examples[name] = x[:, 0, :]          # node 0
                if key == "x_local":
                    node0 = x[:, 0, :]
            mse[name] = err
    if "fused" not in mse and "local" not in mse:
        raise DkfsimError(f"{f}: no estimates (x_fused or x_local) to plot")
    return Folder(path=p, kind="run", scenario=str(summary.get("scenario", p.name)), t=t,
                  components=comps, units=component_units(comps, kind), mse=mse, truth=truth,
                  examples=examples, node0=node0, n_runs=1, d_t=_d_t(summary),
                  burn_in=(summary.get("metrics") or {}).get("burn_in"),
                  links={k: arrays[k] for k in link_keys},
                  mobility=_mobility(f, summary, {k: arrays[k] for k in mobility_keys}),
                  radio=_radio(summary, {k: arrays[k] for k in radio_keys}))


def _radio(summary: dict, arrays: dict) -> dict:
    """A radio run's arrays and the DKF's ``pdr_by_distance`` (summary.json, checked on reading)."""
    pdr = ((summary.get("packets") or {}).get("channel") or {}).get("pdr_by_distance")
    if not arrays and pdr is None:
        return {}
    out = dict(arrays)
    if pdr is not None:
        out["pdr_by_distance"] = pdr
    return out


def _check_mobility(z: NpzFile, summary: dict, K: int) -> list[str]:
    """The mobility arrays' headers against summary.json (before any data is read): present
    together with summary.json's ``mobility`` or not at all, one ``link_uptime`` row per pair."""
    record = summary.get("mobility")
    if "mobility_links" not in z and not any(k in z for k in MOBILITY_ARRAYS):
        if record is not None:
            raise DkfsimError(f"{z.path}: summary.json has mobility but run.npz has no "
                              "mobility_links (the files do not belong together)")
        return []
    if record is None:
        raise DkfsimError(f"{z.path}: holds mobility arrays but summary.json has no mobility "
                          "(the files do not belong together)")
    E = npz_header(z, "mobility_links", (None, 2)).shape[0]
    if E != len(record["link_uptime"]):
        raise DkfsimError(f"{z.path}: array 'mobility_links' has {E} pairs but summary.json's "
                          f"mobility.link_uptime has {len(record['link_uptime'])} rows")
    n = _nodes(summary)
    for key, shape in MOBILITY_ARRAYS.items():
        npz_header(z, key, _dims(shape, K=K, E=E, n=n))
    return ["mobility_links", *MOBILITY_ARRAYS]


def _nodes(summary: dict) -> int | None:
    """The scenario's number of nodes (its sensors in summary.json's scenario_config), if known."""
    sensors = (summary.get("scenario_config") or {}).get("sensors")
    return len(sensors) if isinstance(sensors, list) else None


def _mobility(f: Path, summary: dict, arrays: dict) -> dict:
    """The mobility arrays checked for values (pairs of nodes in the order summary.json gives,
    links_up 0 or 1, finite positions) with summary.json's up-time per pair beside them."""
    if not arrays:
        return {}
    pairs = np.asarray(arrays["mobility_links"])
    n = arrays["positions"].shape[1]
    rows = summary["mobility"]["link_uptime"]
    if pairs.dtype.kind not in "iu" or ((pairs < 0) | (pairs >= n)).any() or (pairs[:, 0] >= pairs[:, 1]).any():
        raise DkfsimError(f"{f}: array 'mobility_links' holds pairs that are not two nodes u < v of 0..{n - 1}")
    if [list(p) for p in pairs.tolist()] != [[int(r[0]), int(r[1])] for r in rows]:
        raise DkfsimError(f"{f}: array 'mobility_links' names other pairs than summary.json's "
                          "mobility.link_uptime")
    up = np.asarray(arrays["links_up"])
    if not np.isin(up, (0, 1)).all():
        raise DkfsimError(f"{f}: array 'links_up' holds values other than 0 and 1")
    pos = np.asarray(arrays["positions"], dtype=float)
    if not np.isfinite(pos).all():
        raise DkfsimError(f"{f}: array 'positions' holds values that are not finite")
    return {"mobility_links": pairs, "positions": pos, "links_up": up.astype(bool),
            "link_uptime": np.array([float(r[2]) for r in rows])}


def _load_montecarlo(p: Path) -> Folder:
    f = p / "curves.npz"
    summary = read_record(p / "summary.json", MonteCarloSummary, "summary.json") \
        if (p / "summary.json").is_file() else {}
    arrays = read_curves(f, summary.get("steps"), summary.get("components"))
    comps, algs = arrays["components"], arrays["estimates"]
    t = arrays["t"].astype(float)
    mse_all = arrays["mse"].astype(float)
    mse = {a: mse_all[i] for i, a in enumerate(algs)}
    ci = {}
    if "mse_ci_lo" in arrays and "mse_ci_hi" in arrays:
        lo, hi = arrays["mse_ci_lo"].astype(float), arrays["mse_ci_hi"].astype(float)
        ci = {a: (lo[i], hi[i]) for i, a in enumerate(algs)}
    examples, truth, node0 = {}, None, None
    if "example_truth" in arrays:
        truth = arrays["example_truth"].astype(float)
        if "example_x" in arrays:
            ex = arrays["example_x"].astype(float)
            examples = {a: ex[i] for i, a in enumerate(algs)}
        if "example_node0" in arrays:
            node0 = arrays["example_node0"].astype(float)
    nees, band = {}, None
    if "nees" in arrays:
        ne = arrays["nees"].astype(float)
        nees = {a: ne[i] for i, a in enumerate(algs)}
        if "nees_band" in arrays:
            b = arrays["nees_band"].astype(float)
            band = (float(b[0]), float(b[1]))
    kind = _model_kind(summary)
    n_runs = None
    if (p / "runs.csv").is_file():
        n_runs = len(read_run_seeds(p / "runs.csv")) or None
    if n_runs is None and summary:
        n_runs = summary["runs"]
    ci95 = {a: e["mse_ci95"] for a, e in (summary.get("estimates") or {}).items()}
    stats = dict(summary.get("estimates") or {})
    return Folder(path=p, kind="montecarlo", scenario=str(summary.get("scenario", p.name)), t=t,
                  components=comps, units=component_units(comps, kind), mse=mse, ci=ci, truth=truth,
                  examples=examples, node0=node0, n_runs=n_runs or 0, d_t=_d_t(summary), nees=nees,
                  nees_band=band, burn_in=summary.get("burn_in"), mse_ci95=ci95, stats=stats,
                  mobility=_replayed_mobility(p / "summary.json", summary, len(t)))


def _replayed_mobility(f: Path, summary: dict, K: int) -> dict:
    """A Monte Carlo folder of a scenario with ``mobility:`` keeps no positions, but they and
    the links up follow from its trajectories and range alone, the same in every run (no draw
    moves a vehicle): replayed here from the stored scenario, validated as data (decision 231).
    Empty without ``mobility:``, and when the stored scenario cannot be read back (a trajectory
    file that is gone): the folder's other figures do not need it."""
    cfg = summary.get("scenario_config")
    if not isinstance(cfg, dict) or cfg.get("mobility") is None:
        return {}
    if cfg.get("steps") != K:             # before any work: a scenario of other runs is not replayed
        raise DkfsimError(f"{f}: scenario_config has steps {clip(cfg.get('steps'))} but curves.npz has "
                          f"{K} ticks (the files do not belong together)")
    try:
        plan = RunPlan.of(stored_scenario(cfg, source=summary.get("source"), label=str(f)))
        schedule = plan.link_schedule
    except DkfsimError:
        return {}
    if schedule is None or plan.positions is None:
        return {}
    pairs, up = link_pairs(schedule)
    return {"mobility_links": pairs, "positions": np.asarray(plan.positions[1:], dtype=float),
            "links_up": up[1:], "link_uptime": np.array([r[2] for r in link_uptime(pairs, up[1:])])}


def _dims(shape: tuple, **sizes) -> tuple:
    """A shape template (``("K", "E")``, ``("E", 101)``) with its named sizes filled in."""
    return tuple(sizes.get(s, s) if isinstance(s, str) else s for s in shape)
