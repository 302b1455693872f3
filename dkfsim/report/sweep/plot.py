"""``dkfsim plot SWEEP``: a metric against one swept key, with 95 % interval bands.

SWEEP is a sweep database or its export (``.csv`` / ``.parquet``).  Each point is
the mean over the runs of one grid point (:mod:`dkfsim.experiments.sweep.grid`), its band
the 95 % Student-t interval over those runs -- the numbers of the summary file
``dkfsim sweep`` writes.  One line per estimate, or with ``--hue KEY`` one line
per value of a second grid key (for one ``--estimate``).  Grid keys that are
neither ``--x`` nor ``--hue`` must be fixed with ``--where KEY=VALUE`` when they
take several values.  A per-component metric (``mse``) gets one panel per state
component; ``anees`` shows the expected value nx (an estimate is consistent where its
interval covers it; the per-tick chi-square band is not a band for the time average).
With ``--relative-to NAME`` each line is the paired ratio of the metric to the
reference at the same grid point, run by run (the exponentiated 95 % t-interval of the
per-run log-ratios: :mod:`dkfsim.analysis.paired`): NAME is an estimate, or with
``--hue`` a value of the hue key (runs pair by run index, so ``seed`` must not be a grid key).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dkfsim.analysis.metrics import paired_interval
from dkfsim.analysis.paired import pair_values, reference_of
from dkfsim.config.dynamics import component_units
from dkfsim.config.keys import key_label
from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import pyplot
from dkfsim.core.params import suggest
from dkfsim.core.registry import METRICS
from dkfsim.experiments.sweep.grid import grid_columns, groups, interval
from dkfsim.experiments.sweep.summary import read_table
from dkfsim.report.plots.style import (
    DEFAULT_FORMATS,
    OPEN_BELOW,
    OTHER_COLORS,
    check_formats,
    color_of,
    estimate_order,
    label_of,
    log_band,
    opens_below,
    plain,
    plain_log_ticks,
    save_figure,
    select_components,
    unit_label,
)

#: y-axis label per metric (docs/estimators.md, "Tidy rows").
METRIC_LABELS = {"mse": "MSE", "anees": "ANEES", "disagreement": "disagreement",
                 "messages_per_tick": "messages per tick", "bytes_per_tick": "bytes per tick",
                 "lost": "lost packets per run",
                 "late": "late information per run [packet rows or contributions]"}

#: Positive numeric grid values spanning more than this factor get a log x axis (link rates).
LOG_X_SPAN = 100.0


def log_x(values: list[float]) -> bool:
    """A log x axis: every value positive and they span more than :data:`LOG_X_SPAN`."""
    return bool(values) and min(values) > 0 and max(values) / min(values) > LOG_X_SPAN


def _key(columns, name: str, flag: str) -> str:
    grid = grid_columns(columns)
    if name in grid:
        return name
    if f"param:{name}" in grid:
        return f"param:{name}"
    tail = [k for k in grid if k.endswith("." + name)]
    if len(tail) == 1:                    # --x d_t for links.default.latency.d_t
        return tail[0]
    raise DkfsimError(f"{flag} {name}: not a grid key of this sweep{suggest(name, grid)} "
                      f"(grid keys: {', '.join(grid) or 'none'})")


def _same(a, b) -> bool:
    return a == b or str(a) == str(b)


def _parse_where(columns, where) -> dict:
    out = {}
    for item in where or ():
        key, sep, value = str(item).partition("=")
        if not sep:
            raise DkfsimError(f"--where {item}: expected KEY=VALUE, e.g. --where protocol=tree")
        out[_key(columns, key.strip(), "--where")] = value.strip()
    return out


def _values(gs, key) -> list:
    seen: list[object] = []
    for g in gs:
        v = g["grid"][key]
        if not any(_same(v, s) for s in seen):
            seen.append(v)
    return seen


def _numeric(values) -> bool:
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)


def per_component(metric: str) -> bool:
    """True for a metric with one value per state component (``mse``)."""
    return metric in METRICS and METRICS.get(metric).implementation.per_component


def sweep_curves(path, x: str | None = None, hue: str | None = None, metric: str = "mse",
                 estimate: str | None = None, where=(), relative_to: str | None = None,
                 components=None, table: tuple | None = None, versus: str | None = None) -> dict:
    """The points to draw: ``{"x": key, "hue": key or None, "xs": values, "lines": {label:
    {component: [(x, n, mean, lo, hi), ...]}}, "components": [...], "nx": {estimate: nx},
    "estimates": every estimate name of the sweep (for :func:`~dkfsim.report.plots.style.color_of`)}``;
    with ``relative_to`` the points are paired ratios to the reference (:func:`_paired`);
    ``components``: the state components kept, by name or index (``--component``; default all);
    ``table``: :func:`read_table` of ``path`` when the caller has read it already; ``versus``
    (with ``hue``): the points are the hue lines' paired ratios to estimate ``versus`` at the same
    grid point (the reference of the issue 34 §6 figures)."""
    columns, rows = read_table(path) if table is None else table
    if metric not in columns:
        metrics = [c for c in columns if c in METRICS]
        raise DkfsimError(f"--metric {metric}: not a column of {path}{suggest(metric, metrics)} "
                          f"(metrics: {', '.join(metrics)})")
    grid = grid_columns(columns)
    if not grid:
        raise DkfsimError(f"{path}: the sweep has no grid keys; there is nothing to plot against")
    if x is None:
        if len(grid) != 1:
            raise DkfsimError(f"{path}: give --x KEY, one of the grid keys: {', '.join(grid)}")
        x = grid[0]
    x = _key(columns, x, "--x")
    hue_key = None if hue in (None, "estimate") else _key(columns, hue, "--hue")
    if hue_key == x:
        raise DkfsimError(f"--hue {hue}: the same key as --x; choose another grid key or 'estimate'")
    fixed = _parse_where(columns, where)
    found = groups(columns, rows)
    gs = [g for g in found.values() if all(_same(g["grid"][k], v) for k, v in fixed.items())]
    if not gs:
        raise DkfsimError(f"--where: no rows of {path} match "
                          + ", ".join(f"{k}={v}" for k, v in fixed.items()))
    for k in grid:
        if k in (x, hue_key) or k in fixed:
            continue
        vals = _values(gs, k)
        if len(vals) > 1:
            raise DkfsimError(f"grid key {k} takes {len(vals)} values ({', '.join(map(str, vals))}): "
                              f"give --hue {k}, or fix it with --where {k}=VALUE")
    names = estimate_order({g["estimate"] for g in gs})
    if relative_to is not None:
        _check_reference(relative_to, names, gs, hue_key, grid)
    if hue_key is not None:
        estimate = estimate or ("fused" if "fused" in names else names[0])
        if estimate not in names:
            raise DkfsimError(f"--estimate {estimate}: not in the sweep{suggest(estimate, names)} "
                              f"(estimates: {', '.join(names)})")
        gs = [g for g in gs if g["estimate"] == estimate]
    elif estimate is not None:
        wanted = [e.strip() for e in str(estimate).split(",")]
        for e in wanted:
            if e not in names:
                raise DkfsimError(f"--estimate {e}: not in the sweep{suggest(e, names)} "
                                  f"(estimates: {', '.join(names)})")
        gs = [g for g in gs if g["estimate"] in wanted]
        names = [n for n in names if n in wanted]
    wanted_components, components = list(components or ()), []
    for g in gs:
        if g["component"] not in components:
            components.append(g["component"])
    if not per_component(metric):
        if wanted_components:
            raise DkfsimError(f"--component: --metric {metric} has one value per run, not one per "
                              "state component (--component is for mse)")
        components = components[:1]       # scalar metrics repeat on every component row
    elif wanted_components:
        components = [components[i] for i in select_components(components, wanted_components, "the sweep")]
    nx: dict[str, set[str]] = {}           # estimate -> its state components
    for g in gs:
        nx.setdefault(g["estimate"], set()).add(g["component"])
    lines: dict = {}
    order = names if hue_key is None else [str(v) for v in _values(gs, hue_key)]
    for label in order:
        lines[label] = {c: [] for c in components}
    for g in gs:
        if g["component"] not in components:
            continue
        label = g["estimate"] if hue_key is None else str(g["grid"][hue_key])
        if relative_to is not None:
            if label == relative_to:
                continue
            point = _paired(g, found, gs, relative_to, hue_key, metric)
        elif versus is not None:
            point = _paired(g, found, gs, versus, None, metric)
        else:
            point = interval(r.get(metric) for r in g["rows"])
        if point is not None:
            lines[label][g["component"]].append((g["grid"][x], len(g["rows"]), *point))
    lines.pop(relative_to, None)
    xs = _values(gs, x)
    return {"x": x, "hue": hue_key, "estimate": estimate if hue_key else None, "xs": xs,
            "estimates": sorted({g["estimate"] for g in found.values()}), "lines": lines, "components": components, "metric": metric, "fixed": fixed,
            "nx": {e: len(c) for e, c in nx.items()},
            "relative_to": relative_to if versus is None else versus}


def _check_reference(ref: str, names, gs, hue_key, grid) -> None:
    """``--relative-to``: an estimate, or with ``--hue`` a value of the hue key, and then runs
    must pair by run index (the same seeds at every grid point: ``seed`` is not a grid key)."""
    if hue_key is None:
        reference_of(names, ref, "the sweep", suggestion=True)
        return
    seeds = [k for k in grid if k.removeprefix("param:") == "seed"]
    if seeds:
        raise DkfsimError("--relative-to with --hue: seed is a grid key, so run r of two grid "
                          "points is not drawn from the same seed and runs cannot be paired; "
                          "compare estimates instead (no --hue)")
    values = [str(v) for v in _values(gs, hue_key)]
    if ref not in values:
        raise DkfsimError(f"--relative-to {ref}: with --hue {hue_key.removeprefix('param:')}, a value of "
                          f"that key{suggest(ref, values)} (values: {', '.join(values)})")


def _paired(g, found, gs, ref: str, hue_key, metric: str):
    """``(ratio, lo, hi)`` of group ``g``'s metric to the reference's, paired by run index;
    None when the reference has no rows there or a ratio is undefined (a value <= 0)."""
    if hue_key is None:
        other = found.get((g["param_hash"], ref, g["component"]))
    else:
        want = {**g["grid"], hue_key: ref}
        other = next((o for o in gs if o["estimate"] == g["estimate"] and o["component"] == g["component"]
                      and all(_same(o["grid"][k], v) for k, v in want.items())), None)
    if other is None:
        return None
    p = paired_interval(*pair_values(g["rows"], other["rows"], metric))
    if p["ratio"] is None:
        return None
    lo, hi = p["ratio_ci95"]
    return (p["ratio"], np.nan if lo is None else lo, np.nan if hi is None else hi)


#: Marker of the i-th line of a sweep figure (by its place among all the sweep's lines, so a
#: line keeps its marker in every panel and column).
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*", "<", ">", "h", "p")
#: Line styles of a line drawn over ones it coincides with (the k-th such line: DASHES[k - 1]).
DASHES = ("--", (0, (1, 1.5)), "-.", (0, (5, 2, 1, 2, 1, 2)), (0, (3, 1)))
#: Two lines coincide where they differ by less than this fraction of the panel's range.
COINCIDE = 0.015


def coinciding(series, log: bool) -> list[int]:
    """For each line ``(xs, ys)`` of a panel, drawn in order, how many lines drawn before it
    it coincides with (at every x they share, closer than :data:`COINCIDE` of the panel's
    range, on the panel's scale).  A line over k others is drawn hollow, larger and dashed,
    so that each one stays visible (docs/decisions.md, 199)."""
    def scaled(ys):
        ys = np.asarray(ys, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(ys > 0, np.log10(ys), np.nan) if log else ys
    vals = [dict(zip(map(str, xs), scaled(ys))) for xs, ys in series]
    every = np.array([v for d in vals for v in d.values()], dtype=float)
    every = every[np.isfinite(every)]
    span = float(every.max() - every.min()) if every.size else 0.0
    tol = COINCIDE * (span if span > 0 else max(1.0, float(np.abs(every).max()) if every.size else 1.0))
    out = []
    for j, d in enumerate(vals):
        k = 0
        for e in vals[:j]:
            shared = [x for x in d if x in e and np.isfinite(d[x]) and np.isfinite(e[x])]
            if shared and all(abs(d[x] - e[x]) <= tol for x in shared):
                k += 1
        out.append(k)
    return out


def line_style(index: int, over: int) -> dict:
    """Matplotlib keywords of the line with marker ``index`` drawn over ``over`` coinciding lines."""
    style = {"marker": MARKERS[index % len(MARKERS)], "ms": 4.0, "lw": 1.2, "ls": "-"}
    if over:
        style.update(ms=4.0 + 2.4 * over, mfc="none", mew=1.2, ls=DASHES[(over - 1) % len(DASHES)])
    return style


def tick_texts(values) -> list[str]:
    """Tick labels of numeric grid values in one notation: SI prefixes when the largest is 10^4 or
    more (``100k``, ``1M``, ``12M``: a rate axis read ``500000`` beside ``1e+06`` before, issue 34
    §6), else ``%g``."""
    nums = [float(v) for v in values]
    top = max((abs(v) for v in nums), default=0.0)
    if top < 1e4:
        return [f"{v:g}" for v in nums]
    out = []
    for v in nums:
        for prefix, size in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
            if abs(v) >= size:
                out.append(f"{v / size:.4g}{prefix}")
                break
        else:
            out.append(f"{v:.4g}")
    return out


def axis_label(key: str, xlabel: str | None = None) -> str:
    """The x label of grid key ``key``: ``--xlabel`` when given, else what the key is and its
    unit (:func:`dkfsim.config.keys.key_label`), ``per-hop delay bound d_t [ticks]``."""
    if xlabel is not None:
        return plain(xlabel)
    words, unit = key_label(key)
    return f"{plain(words)} [{plain(unit)}]" if unit else plain(words)


def hue_color(j: int, n: int, cmap):
    """The colour of the j-th of n hue values: never a built-in estimate's colour (a hue value
    is not an estimate): :data:`OTHER_COLORS`, or a colour map beyond them."""
    return OTHER_COLORS[j] if n <= len(OTHER_COLORS) else cmap(0.9 * j / (n - 1))


def _draw_column(axes, cur, comps, pos, styles, cmap, single: bool = True,
                 dashed: bool = False) -> tuple[int, set, bool]:
    """Draw the lines of :func:`sweep_curves` result ``cur`` into one column of panels; return
    the number of data lines drawn (reference lines do not count), the run counts seen and
    whether a band was opened below (:func:`~dkfsim.report.plots.style.log_band`)."""
    ref, metric = cur["relative_to"], cur["metric"]
    units = component_units(comps, None) if per_component(metric) else [""] * len(comps)   # by the names
    n_lines = len(styles)
    drawn, runs, opened = 0, set[int](), False
    # One scale for every panel of the column: a log axis when any panel spans more than 10x
    # (position on a linear axis beside velocity on a log one read as different things, issue 34 §6).
    every = np.array([p[2] for by_comp in cur["lines"].values() for comp in comps for p in by_comp[comp]],
                     dtype=float)
    every = every[np.isfinite(every) & (every > 0)]
    log_column = (metric == "mse" or ref is not None) and every.size > 0 and every.max() / every.min() > 10
    for ax, comp in zip(axes, comps):
        series = []
        for label, by_comp in cur["lines"].items():
            pts = sorted(by_comp[comp], key=lambda p: pos[str(p[0])])
            m = np.array([p[2] for p in pts], dtype=float)
            if not pts or np.isnan(m).all():
                continue                      # not applicable to this estimate: no legend entry
            runs.update(p[1] for p in pts)
            series.append((label, [p[0] for p in pts], m, np.array([p[3] for p in pts], dtype=float),
                           np.array([p[4] for p in pts], dtype=float)))
        vals = np.concatenate([m for *_, m, _lo, _hi in series]) if series else np.array([])
        vals = vals[np.isfinite(vals) & (vals > 0)]
        log = log_column and vals.size > 0
        overs = coinciding([(xs, m) for _, xs, m, _, _ in series], log)
        for (label, xs, m, lo, hi), over in zip(series, overs):
            j = list(styles).index(label)
            if cur["hue"] is None:
                col, lab = color_of(label, cur["estimates"]), label_of(label)
            else:
                col, lab = hue_color(j, n_lines, cmap), f"{plain(cur['hue'].removeprefix('param:'))} = {plain(label)}"
            px = [pos[str(v)] for v in xs]
            if dashed:                        # a reference beside its hue line: same colour, dashed
                ax.plot(px, m, color=col, lw=1.0, ls="--", alpha=0.85, zorder=1, label="_reference")
                continue
            ax.plot(px, m, color=col, label=lab, zorder=2 + over, **line_style(styles[label], over))
            drawn += 1
            if not np.isnan(lo).all():
                if log:
                    opened |= opens_below(lo)
                    lo, hi = log_band(lo, hi, m)
                ax.fill_between(px, lo, hi, color=col, alpha=0.15, lw=0)
        if dashed:
            if log and ax.get_yscale() == "log":          # keep the panel's scale, widened to show them
                lo_, hi_ = ax.get_ylim()
                ax.set_ylim(min(lo_, vals.min() / 1.6), max(hi_, vals.max() * 1.6))
            continue
        if ref is not None:
            ax.axhline(1.0, color="0.3", lw=0.8, ls=":", zorder=1)
        elif metric == "anees" and cur["nx"] and len(set(cur["nx"].values())) == 1:
            nx = next(iter(cur["nx"].values()))
            ax.axhline(nx, color="0.3", lw=0.8, ls=":", zorder=1,
                       label=f"nx = {nx}: consistent where the 95 % interval covers it")
        if log:
            ax.set_yscale("log")
            plain_log_ticks(ax)
            ax.set_ylim(vals.min() / 1.6, vals.max() * 1.6)   # the means, not bands reaching to 0
        name = METRIC_LABELS.get(metric, metric)
        unit = unit_label(units[comps.index(comp)], squared=True) if metric == "mse" and ref is None else ""
        if ref is not None:               # beside the absolute column, its title names the hue key
            hue = "" if cur["hue"] is None or not single else plain(cur["hue"].removeprefix("param:")) + " = "
            name = f"{name} / {hue}{plain(ref)}"
        ax.set_ylabel(f"{plain(comp)} {plain(name)}{unit}" if len(comps) > 1 or metric == "mse" else plain(name))
        ax.grid(True, which="major", alpha=0.3)
        ax.grid(True, which="minor", alpha=0.1)
    return drawn, runs, opened


def plot_sweep(path, stem, x=None, hue=None, metric="mse", estimate=None, where=(),
               formats=DEFAULT_FORMATS, title=None, relative_to=None, components=None,
               xlabel=None) -> list[Path]:
    """Draw :func:`sweep_curves` into ``stem.<format>``; return the files written.

    ``mse`` gets a second column of panels, each estimate's paired ratio to the reference
    (``relative_to``; default ``centralized`` when the sweep has it and there is no ``hue``);
    another metric with ``relative_to`` is drawn as the ratio alone.  ``xlabel`` replaces the
    x label made from the key (:func:`axis_label`)."""
    formats = check_formats(formats)
    table = read_table(path)               # once for both columns of panels
    absolute = sweep_curves(path, x, hue, metric, estimate, where, None, components, table)
    ref = relative_to
    if ref is None and metric == "mse" and absolute["hue"] is None and "centralized" in absolute["estimates"] \
            and len(absolute["lines"]) > 1:
        ref = "centralized"
    cols = [] if ref is not None and metric != "mse" else [absolute]
    if ref is not None:
        cols.append(sweep_curves(path, x, hue, metric, estimate, where, ref, components, table))
    # With --hue the lines are one estimate's (fused): its reference (centralized) at the same grid
    # points is drawn dashed in each hue's colour, and the paired ratio to it beside, as a Monte
    # Carlo's figures do (issue 34 §6).
    versus = None
    if relative_to is None and metric == "mse" and absolute["hue"] is not None \
            and "centralized" in absolute["estimates"] and absolute["estimate"] != "centralized":
        versus = "centralized"
        cols.append(sweep_curves(path, x, hue, metric, estimate, where, None, components, table, versus=versus))
        reference = sweep_curves(path, x, hue, metric, "centralized", where, None, components, table)
    cur = cols[0]
    comps, xs = cur["components"], cur["xs"]
    numeric = _numeric(xs)
    pos = {str(v): (float(v) if numeric else i) for i, v in enumerate(xs)}
    styles = {label: j for j, label in enumerate(absolute["lines"])}
    plt = pyplot()
    fig, axes = plt.subplots(len(comps), len(cols), figsize=(6.4 if len(cols) == 1 else 11.0,
                             2.4 * len(comps) + 1.0), sharex=True, squeeze=False)
    cmap = plt.get_cmap("viridis")
    drawn, runs, opened = 0, set[int](), False
    for c, col in enumerate(cols):
        n, seen, o = _draw_column(axes[:, c], col, comps, pos, styles, cmap, single=len(cols) == 1)
        drawn, runs, opened = drawn + n, runs | seen, opened or o
    if versus is not None:
        _draw_column(axes[:, 0], reference, comps, pos, styles, cmap, dashed=True)
    if not drawn:
        plt.close(fig)
        raise DkfsimError(f"--metric {metric}: nothing to draw, no value of {metric} is known in the "
                          "selected rows (every one is empty: not applicable)")
    xname = cur["x"].removeprefix("param:")
    for c in range(len(cols)):
        last = axes[-1, c]
        last.set_xlabel(axis_label(cur["x"], xlabel))
        wide = numeric and log_x([float(v) for v in xs])
        if wide:
            last.set_xscale("log")
            last.minorticks_off()
            last.set_xlabel(last.get_xlabel() + " (log axis)")
        if numeric:
            last.set_xticks([float(v) for v in xs])
            last.set_xticklabels(tick_texts(xs))
            if wide:                         # values close on a long axis: labels upright
                last.tick_params(axis="x", labelrotation=90, labelsize=8)
        else:
            last.set_xticks(range(len(xs)))
            last.set_xticklabels([plain(v, 40) for v in xs])
    if len(cols) == 2:
        axes[0, 0].set_title("mean over the runs" + (f"; dashed: {label_of(versus)}" if versus else ""),
                             fontsize=9.5)
        if versus is not None:
            axes[0, 1].set_title(f"{plain(cur['estimate'])} / {plain(versus)} at each point: paired ratio, "
                                 "run by run", fontsize=9.5)
        else:
            hue = "" if cur["hue"] is None else plain(cur["hue"].removeprefix("param:")) + " = "
            axes[0, 1].set_title(f"relative to {hue}{plain(ref)}: paired ratio, run by run", fontsize=9.5)
    r = sorted(runs)
    per = f"{r[0]} runs" if len(r) == 1 else f"{r[0]}-{r[-1]} runs"
    what = METRIC_LABELS.get(metric, metric)
    mean = f"mean over {per} per point; band: 95 % interval (Student t)"
    ratio = "ratio: geometric mean of the per-run ratios, band: 95 % t-interval of their logs"
    sub = ratio.replace("ratio: ", f"paired over {per} per point: ") if cols[0]["relative_to"] else \
        mean + ("" if len(cols) == 1 else f";\n{ratio}")
    if cur["estimate"]:
        sub = f"{label_of(cur['estimate'])}; " + sub
    fixed = [f"{plain(k.removeprefix('param:'))} = {plain(v, 40)}" for k, v in cur["fixed"].items()]
    sub += "; x: " + ", ".join([plain(xname)] + fixed) + (f";\n{OPEN_BELOW}" if opened else "")
    words = axis_label(cur["x"]) if xlabel is None else plain(xlabel)
    fig.suptitle((plain(title) if title else f"{plain(what)} against {words}") + f"\n({sub})",
                 fontsize=10.5)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    if versus is not None:
        handles.append(axes[0, 0].plot([], [], color="0.4", lw=1.0, ls="--")[0])
        labels.append(f"{label_of(versus)} at the same point (dashed, the line's colour)")
    fig.tight_layout()
    if labels:
        fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.0),
                   ncol=min(len(labels), 2 if len(cols) == 1 else 3), fontsize=8.5, frameon=False)
    return save_figure(fig, stem, formats)
