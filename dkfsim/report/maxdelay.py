"""The figure of ``dkfsim maxdelay``: the metric against the delay, and what the decisions use.

Drawn from a :class:`~dkfsim.experiments.maxdelay.report.MaxDelayResult` with the plot style
every figure shares (:mod:`dkfsim.report.plots.style`): the estimate's colour, one legend below
the panels, names drawn as plain text, PNG and PDF written atomically.  ``dkfsim maxdelay``
writes it beside ``maxdelay.json`` (:func:`save_maxdelay`).
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np

from dkfsim.core.extras import optional, pyplot
from dkfsim.experiments.maxdelay.report import axis_label, metric_label, number_text, pow10_text, reference_name
from dkfsim.experiments.maxdelay.search import EXCEEDS, UNDECIDED, WITHIN, tracked_estimate
from dkfsim.report.plots.style import DEFAULT_FORMATS, check_formats, color_of, legend_below, plain, save_figure

#: Colours of the decisions, the worst case and the paper bound: none within 0.18 (RGB distance)
#: of a built-in estimate's colour or of the palette of other names (``OTHER_COLORS``), so that
#: no line reads as an estimate (``no_buffer``, ``centralized_delayed``, ``ci_consensus`` and
#: ``kcf`` had C1-C4; ``local_only`` the grey).
COLORS = {"within": "#006d2c", "exceeds": "#67000d", "undecided": "0.72", "worst": "#fdae61",
          "paper": "#2d004b"}


def plot_maxdelay(result, stem, formats=DEFAULT_FORMATS) -> dict:
    """``stem.png`` / ``.pdf``: the metric against the delay (top) and the excess over the
    tolerance that the decisions use (bottom).  Returns the axis labels, legend entries and
    texts drawn (``xlabel``, ``ylabel``, ``legend``, ``texts``), for tests."""
    formats = check_formats(formats)
    estimate = tracked_estimate(result.md.st)
    plt = pyplot()
    MaxNLocator = optional("matplotlib.ticker").MaxNLocator
    md, st, ax = result.md, result.md.st, result.md.axis
    fig, (top, bot) = plt.subplots(2, 1, figsize=(10, 7), sharex=True,
                                   gridspec_kw={"height_ratios": [3, 2]})
    worst, paper = COLORS["worst"], COLORS["paper"]
    cs = sorted(md.cands.values(), key=lambda c: c.index)
    x = np.array([c.delay for c in cs], float)
    colours = {WITHIN: COLORS["within"], EXCEEDS: COLORS["exceeds"], UNDECIDED: COLORS["undecided"]}
    seen = {c.decision for c in cs}
    # -- top: the metric
    top.fill_between(x, [c.ci[0] for c in cs], [c.ci[1] for c in cs], color=color_of(estimate), alpha=0.25, lw=0,
                     label=f"{100 * st.confidence:g}% confidence band (Monte Carlo)")
    top.plot(x, [c.mean for c in cs], "-", color=color_of(estimate), lw=1.2, label=f"{st.metric}, Monte Carlo mean")
    for c in cs:                          # run counts above the points, over any vertical line
        top.plot([c.delay], [c.mean], "o", color=colours[c.decision], ms=5, zorder=5)
        top.annotate(str(c.runs), (c.delay, c.ci[1] if math.isfinite(c.ci[1]) else c.mean),
                     textcoords="offset points", xytext=(0, 4), ha="center", va="bottom", fontsize=7,
                     color="0.2", zorder=7, bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none"))
    for dec, col in colours.items():
        if dec not in seen:              # no legend entry for what did not occur
            continue
        top.plot([], [], "o", color=col, ms=5,
                 label={WITHIN: "decided within", EXCEEDS: "decided exceeds",
                        UNDECIDED: "undecided (run cap)"}[dec])
    if st.relative is None:
        top.axhline(st.tolerance, color="k", ls="--", lw=1, label=f"tolerance {st.tolerance:g}")
    elif result.reference:
        r = result.reference
        top.axhline(r["tolerance"], color="k", ls="--", lw=1,
                    label=f"tolerance {st.relative:g} x {reference_name(ax)} mean")
        top.axhspan(*r["tolerance_ci"], color="k", alpha=0.08, lw=0,
                    label=f"{st.relative:g} x its confidence interval")
    if result.emp.answer is not None:
        top.axvline(ax.value(result.emp.answer), color=color_of(estimate), ls=":", lw=2, zorder=1,
                    label=f"empirical answer {ax.value(result.emp.answer):.4g} ({result.emp.status})")
    ws = sorted(md.wc.values(), key=lambda c: c.index)
    if ws:
        top.plot([c.delay for c in ws], [c.mean for c in ws], "s-", color=worst, ms=3.5, lw=1.2,
                 label="worst case: every link at its largest latency (covariance)")
        if st.relative is not None and result.wc_tol is not None:
            top.axhline(result.wc_tol, color=worst, ls="--", lw=0.8, label="worst-case tolerance")
        if result.limit is not None:
            shown = [v for c in cs + ws for v in (c.mean, *getattr(c, "ci", ())) if math.isfinite(v)]
            shown += [v for v in (st.tolerance, result.wc_tol,
                                  (result.reference or {}).get("tolerance")) if v is not None]
            lo_data, hi_data = (min(shown), max(shown)) if shown else (result.limit, result.limit)
            span = max(hi_data - lo_data, 1e-12 * max(abs(hi_data), 1.0))
            if result.limit > hi_data + 0.5 * span:    # far above: keep the axis on the data
                top.set_ylim(lo_data - 0.08 * span, hi_data + 0.22 * span)
                label = f"worst case with no exchange at all: {result.limit:.4g} (above the axis)"
            else:
                label = "worst case with no exchange at all"
            top.axhline(result.limit, color=worst, ls=(0, (1, 3)), lw=1, label=label)
        if result.wc is not None and result.wc.answer is not None:
            top.axvline(ax.value(result.wc.answer), color=worst, ls=":", lw=2, zorder=1,
                        label=f"worst-case answer {ax.value(result.wc.answer):g} ({result.wc.status})")
    p = result.paper
    if "error" not in p:
        dax = p.get("d_star_in_axis_units")
        if p["meaningful"] and dax is not None:
            top.axvline(dax, color=paper, ls="-.", lw=1.5, zorder=1, label=f"paper bound {dax:.3g}")
        txt = (f"paper bound, eq. (delay_bound): d_t <= {number_text(p['d_star'])}"
               + ("" if p["meaningful"] else " (meaningless)") +
               f"\nit guarantees lambda_max(P) <= {pow10_text(p['log10_lambda_max_bound']['0'])} at d_t = 0, "
               f"{pow10_text(p['log10_lambda_max_bound']['1'])} at d_t = 1")
        top.text(0.01, 0.98, txt, transform=top.transAxes, va="top", fontsize=7.5, color=paper,
                 bbox=dict(boxstyle="round", fc="white", ec=paper, alpha=0.85), zorder=8)
    bound = getattr(result, "rate_bound", None)
    if bound and "error" not in bound:
        top.axvline(bound["rate"], color=paper, ls="-.", lw=1.5,
                    label=f"lower bound from the packet sizes {bound['rate']:.3g} bit/s (utilisation 1 on "
                          f"link {bound['link'][0]}->{bound['link'][1]})")
    top.set_ylabel("\n".join(textwrap.wrap(plain(metric_label(st.metric, md.comp_name, md.sc)), 30)))
    least = "Least" if ax.mode == "rate" else "Largest"
    top.set_title(f"{least} {plain(ax.name)} within tolerance (point labels: Monte Carlo runs)", fontsize=10)
    top.grid(alpha=0.3)
    # -- bottom: what the decisions use
    for c in cs:
        lo, hi = c.excess_ci
        top_err = [[c.excess_mean - lo], [hi - c.excess_mean]] if math.isfinite(lo) else None
        bot.errorbar([c.delay], [c.excess_mean], yerr=top_err, fmt="o", color=colours[c.decision],
                     ms=4, capsize=3)
    if ws and result.wc_tol is not None:
        bot.plot([c.delay for c in ws], [c.mean - result.wc_tol for c in ws], "s-", color=worst, ms=3,
                 lw=0.8, label="worst case minus its tolerance")
    bot.axhline(0.0, color="k", lw=1)
    bot.plot([], [], "o", color="0.3", label="below: mean and CI of " +
             ("metric - tolerance" if st.relative is None else
              f"metric_d[r] - {st.relative:g} metric_0[r], paired"))
    bot.set_ylabel("excess over tolerance\n(units of the metric)")
    bot.set_xlabel(axis_label(ax))
    bot.grid(alpha=0.3)
    if ax.mode == "d_t":
        bot.xaxis.set_major_locator(MaxNLocator(integer=True))
    elif ax.mode == "rate":
        bot.set_xscale("log")
    legend_below(fig, [top, bot], ncol=3, fontsize=7.5)
    fig.align_ylabels([top, bot])
    drawn = {"xlabel": bot.get_xlabel(), "ylabel": top.get_ylabel().replace("\n", " "),
             "legend": [t.get_text() for t in fig.legends[0].get_texts()],
             "texts": [t.get_text() for t in top.texts]}
    save_figure(fig, stem, formats)
    return drawn


def save_maxdelay(result, out_dir) -> Path:
    """``maxdelay.json`` and the figure in ``out_dir``, the folder replaced atomically."""
    return result.save(out_dir, figure=plot_maxdelay)
