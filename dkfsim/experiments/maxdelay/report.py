"""The result of ``dkfsim maxdelay``: ``maxdelay.json``, the text table and the figure.

See :mod:`dkfsim.experiments.maxdelay` and docs/design.md.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from dkfsim.config.dynamics import CA_UNITS
from dkfsim.config.load import scenario_hash
from dkfsim.core.extras import optional, pyplot
from dkfsim.core.folders import staged, write_json
from dkfsim.engine.results import versions
from dkfsim.experiments.maxdelay.search import EXCEEDS, METRICS, UNDECIDED, WITHIN, SearchResult, interval, json_number

#: Units of the constant-acceleration model's components (other models have none).


def _pow10(x) -> str:
    """``10**x`` as a plain number (``0.8812``, ``3.2e+05``), not ``10^-0.0549``."""
    try:
        x = float(x)
    except (TypeError, ValueError):
        return "n/a"
    if not math.isfinite(x) or abs(x) > 300:
        return f"10^{x:.3g}"
    return f"{10 ** x:.4g}"


def axis_label(ax) -> str:
    """The delay axis with its unit."""
    return "delay bound d_t [ticks]" if ax.mode == "d_t" else "latency scale s [× the scenario's latencies]"


def cap_option(ax) -> str:
    """The option that raises the last candidate of the delay axis."""
    return "--max-delay" if ax.mode == "d_t" else "--max-scale"


def metric_label(metric: str, comp_name, sc) -> str:
    """The metric with its unit (squared state units for an MSE or a variance)."""
    unit = CA_UNITS.get(comp_name) if sc.model.kind == "constant_acceleration" else None
    sq = f" [({unit})²]" if unit and "/" in unit else (f" [{unit}²]" if unit else "")
    if metric == "trace_P":
        return "trace of P_fused (sum of the state variances; mixed units)"
    what = {"fused_var": "fused variance"}.get(metric, "MSE" if "mse" in metric else metric)
    return f"{comp_name} {what}{sq}" if comp_name else f"{what} (sum over components)"


class MaxDelayResult:
    """The three answers of one search; ``md`` is the
    :class:`~dkfsim.experiments.maxdelay.run.MaxDelay` that produced them."""

    def __init__(self, md, emp: SearchResult, wc: SearchResult | None, wc_tol, limit,
                 paper: dict, runs_empirical: int, runs_total: int, wall: float):
        self.md, self.emp, self.wc, self.wc_tol, self.limit = md, emp, wc, wc_tol, limit
        self.paper, self.runs_empirical, self.runs_total, self.wall = paper, runs_empirical, runs_total, wall
        st = md.st
        self.reference = None
        if st.relative is not None and md.ref:
            det = md.candidate_scenario(0)[1]
            m, ci = interval(md.ref[:1] if det else md.ref, st.confidence)
            self.reference = {"runs": 1 if det else len(md.ref), "deterministic": det,
                              "mean": m, "ci": list(ci),
                              "tolerance": st.relative * m,
                              "tolerance_ci": [st.relative * ci[0], st.relative * ci[1]]}

    @property
    def answer(self):
        a = self.emp.answer
        return None if a is None else self.md.axis.value(a)

    def _search_dict(self, res: SearchResult | None, cands: dict) -> dict | None:
        if res is None:
            return None
        ax = self.md.axis

        def at(j):
            if j is None or j not in cands:
                return None
            c = cands[j]
            return {"delay": c.delay, "runs": c.runs, "mean": json_number(c.mean), "ci": [json_number(v) for v in c.ci],
                    "excess_ci": [json_number(v) for v in c.excess_ci], "decision": c.decision}
        return {
            "status": res.status,
            "answer": None if res.answer is None else ax.value(res.answer),
            "point_estimate": None if res.point is None else ax.value(res.point),
            "first_exceeding": None if res.first_exceeding is None else ax.value(res.first_exceeding),
            "non_monotone": res.non_monotone,
            "at_answer": at(res.answer),
            "at_answer_plus_1": at(None if res.answer is None else res.answer + 1),
            "candidates": [c.to_dict() for c in sorted(cands.values(), key=lambda c: c.index)],
        }

    def to_dict(self) -> dict:
        md, st, sc = self.md, self.md.st, self.md.sc
        paper = {k: v for k, v in self.paper.items() if k != "_object"}
        return {
            "scenario": sc.name, "source": sc.source, "scenario_hash": scenario_hash(sc),
            "steps": sc.steps, "base_seed": sc.seed,
            "seed_rule": "run r uses dkfsim.experiments.montecarlo.derive_seed(base_seed, r) at every candidate "
                         "(common random numbers)",
            "axis": md.axis.describe(),
            "metric": {"name": st.metric, "description": METRICS[st.metric],
                       "component": md.comp_name, "burn_in": md.burn},
            "tolerance": {"kind": "absolute" if st.relative is None else "relative",
                          "value": st.tolerance, "relative": st.relative, "reference": self.reference,
                          "rule": ("per run: metric - tolerance" if st.relative is None else
                                   "per run r: metric_d[r] - relative * metric_0[r] (paired, same seeds)")},
            "confidence": st.confidence, "batch": st.batch, "max_runs": st.max_runs,
            "empirical": {**self._search_dict(self.emp, md.cands), "runs": self.runs_empirical},
            "worst_case": None if self.wc is None else {
                **self._search_dict(self.wc, md.wc),
                "metric": "covariance counterpart: " + ("trace(P)" if st.metric == "trace_P" or
                                                         md.comp is None else
                                                         f"P[{md.comp_name}]") +
                          (" of the node estimates, mean over nodes" if st.metric == "local_mse" else
                           " of the fused estimate"),
                "tolerance": self.wc_tol,
                "no_exchange_limit": self.limit,
                "never_exceeds": None if self.limit is None or self.wc_tol is None else
                bool(self.limit <= self.wc_tol)},
            "paper_bound": paper,
            "runs_total": self.runs_total,
            "notes": md.notes + self._notes(),
            "wall_time_s": self.wall,
            "versions": versions(),
        }

    def _notes(self) -> list[str]:
        out = []
        if self.emp.non_monotone:
            out.append("empirical: a delay decided within lies above one decided exceeding: the metric "
                       "is not monotone in the delay here, and the bisection's answer is not the "
                       "largest delay with the property")
        if self.wc is not None and self.wc.non_monotone:
            out.append("worst case: the covariance metric decreases somewhere along the delay axis "
                       "(optimal fusion of local estimates that share stale information can be worse "
                       "than of less correlated ones); the worst-case answer is the largest delay with "
                       "every smaller one within (a scan), so it accounts for that")
        if self.limit is not None and self.wc_tol is not None and self.limit <= self.wc_tol:
            out.append(f"even with no exchange at all within the run the covariance metric is "
                       f"{self.limit:.4g} <= {self.wc_tol:.4g}: no delay can break this tolerance")
        return out

    def save(self, out_dir) -> Path:
        """Write ``maxdelay.json`` and the figure; the folder is replaced atomically."""
        data = self.to_dict()
        with staged(out_dir, "maxdelay") as tmp:
            write_json(tmp / "maxdelay.json", data)
            self.plot(tmp)
        return Path(out_dir)

    # ------------------------------------------------------------------ text
    def table(self) -> str:
        md, st, ax = self.md, self.md.st, self.md.axis
        d = self.to_dict()
        unit = "d_t" if ax.mode == "d_t" else "s"
        tol = (f"<= {st.tolerance:g}" if st.relative is None else
               f"<= {st.relative:g} x zero-delay value")
        lines = [f"{md.sc.name}: largest {ax.name} with {st.metric}"
                 f"{'' if st.metric == 'trace_P' else ' (' + md.comp_name + ')'} {tol}, "
                 f"{100 * st.confidence:g}% confidence, {md.sc.steps} ticks, burn-in {md.burn}"]
        if self.reference:
            r = self.reference
            how = "deterministic" if r["deterministic"] else f"{r['runs']} runs"
            lines.append(f"  zero-delay value {r['mean']:.4g} [{r['ci'][0]:.4g}, {r['ci'][1]:.4g}] "
                         f"({how}) -> tolerance {r['tolerance']:.4g}")
        e = d["empirical"]
        lines.append(f"  (1) empirical:   {_answer_text(e, unit, cap_option(ax))}  ({self.runs_empirical} runs)")
        for key, what in (("at_answer", "at answer"), ("at_answer_plus_1", "at answer+1")):
            a = e[key]
            if a:
                lines.append(f"        {what:12s} {unit} = {a['delay']:g}: mean {a['mean']:.4g} "
                             f"CI [{a['ci'][0]:.4g}, {a['ci'][1]:.4g}]; excess over tolerance CI "
                             f"[{a['excess_ci'][0]:+.3g}, {a['excess_ci'][1]:+.3g}]; {a['runs']} runs, "
                             f"{a['decision']}")
        w = d["worst_case"]
        if w is None:
            lines.append("  (2) worst case:  not computed (unbounded latency without links.d_t)")
        else:
            lines.append(f"  (2) worst case:  {_answer_text(w, unit, cap_option(ax))}  (every link at its largest "
                         f"latency; tolerance {w['tolerance']:.4g}; no-exchange limit "
                         f"{w['no_exchange_limit']:.4g})")
        p = d["paper_bound"]
        if "error" in p:
            lines.append(f"  (3) paper bound: not computed: {p['error']}")
        else:
            ds = p["d_star"]
            lines.append(
                f"  (3) paper bound: d* = {_fmt(ds)} -> "
                f"{'d_t <= %d' % p['d_t_bound'] if p['meaningful'] else 'MEANINGLESS (no delay guaranteed)'}; "
                f"terms: n = {p['n']}, "
                f"n_bar = {p['n_bar']}, Z = {p['Z']}, alpha_bar = {p['alpha_used']:.4g}, "
                f"eta = {p['eta']:.6g}, gamma_hat = {p['gamma_hat']:.4g}, omega_min = {p['omega_min']:.4g} "
                f"(literal {p['omega_min_literal']:.4g}), p_tol = {p['p_tol']:.4g}")
            lines.append(f"        guaranteed lambda_max(P) <= {_pow10(p['log10_lambda_max_bound']['0'])} at "
                         f"d_t = 0, {_pow10(p['log10_lambda_max_bound']['1'])} at d_t = 1, "
                         f"{_pow10(p['log10_lambda_max_bound']['4'])} at d_t = 4")
            if p["note"]:
                lines.append(f"        {p['note']}")
        for n in d["notes"]:
            lines.append(f"  note: {n}")
        lines.append(f"  {self.runs_total} runs in {self.wall:.1f} s")
        return "\n".join(lines)

    # ------------------------------------------------------------------ plot
    def plot(self, out: Path) -> dict:
        """``maxdelay.png`` / ``.pdf`` (300 dpi): the metric against the delay (top) and the
        excess over the tolerance that the decisions use (bottom).  Returns the axis labels
        and legend entries drawn (``xlabel``, ``ylabel``, ``legend``), for tests."""
        plt = pyplot()
        MaxNLocator = optional("matplotlib.ticker").MaxNLocator
        md, st, ax = self.md, self.md.st, self.md.axis
        fig, (top, bot) = plt.subplots(2, 1, figsize=(10, 7), sharex=True,
                                       gridspec_kw={"height_ratios": [3, 2]})
        cs = sorted(md.cands.values(), key=lambda c: c.index)
        x = np.array([c.delay for c in cs], float)
        colours = {WITHIN: "C2", EXCEEDS: "C3", UNDECIDED: "0.5"}
        seen = {c.decision for c in cs}
        # -- top: the metric
        top.fill_between(x, [c.ci[0] for c in cs], [c.ci[1] for c in cs], color="C0", alpha=0.25, lw=0,
                         label=f"{100 * st.confidence:g}% confidence band (Monte Carlo)")
        top.plot(x, [c.mean for c in cs], "-", color="C0", lw=1.2, label=f"{st.metric}, Monte Carlo mean")
        for c in cs:
            top.plot([c.delay], [c.mean], "o", color=colours[c.decision], ms=5, zorder=5)
            top.annotate(str(c.runs), (c.delay, c.ci[1] if math.isfinite(c.ci[1]) else c.mean),
                         textcoords="offset points", xytext=(0, 3), ha="center", fontsize=7, color="0.3")
        for dec, col in colours.items():
            if dec not in seen:              # no legend entry for what did not occur
                continue
            top.plot([], [], "o", color=col, ms=5,
                     label={WITHIN: "decided within", EXCEEDS: "decided exceeds",
                            UNDECIDED: "undecided (run cap)"}[dec])
        if st.relative is None:
            top.axhline(st.tolerance, color="k", ls="--", lw=1, label=f"tolerance {st.tolerance:g}")
        elif self.reference:
            r = self.reference
            top.axhline(r["tolerance"], color="k", ls="--", lw=1,
                        label=f"tolerance {st.relative:g} x zero-delay mean")
            top.axhspan(*r["tolerance_ci"], color="k", alpha=0.08, lw=0,
                        label=f"{st.relative:g} x its confidence interval")
        if self.emp.answer is not None:
            top.axvline(ax.value(self.emp.answer), color="C0", ls=":", lw=2,
                        label=f"empirical answer {ax.value(self.emp.answer):g} ({self.emp.status})")
        ws = sorted(md.wc.values(), key=lambda c: c.index)
        if ws:
            top.plot([c.delay for c in ws], [c.mean for c in ws], "s-", color="C1", ms=3.5, lw=1,
                     label="worst case: every link at its largest latency (covariance)")
            if st.relative is not None and self.wc_tol is not None:
                top.axhline(self.wc_tol, color="C1", ls="--", lw=0.8, label="worst-case tolerance")
            if self.limit is not None:
                shown = [v for c in cs + ws for v in (c.mean, *getattr(c, "ci", ())) if math.isfinite(v)]
                shown += [v for v in (st.tolerance, self.wc_tol,
                                      (self.reference or {}).get("tolerance")) if v is not None]
                top_of_data = max(shown) if shown else self.limit
                if self.limit > 2.0 * top_of_data:    # far above: keep the axis on the data
                    lo_y = min(min(shown), 0.0)
                    top.set_ylim(lo_y, top_of_data + 0.15 * (top_of_data - lo_y))
                    label = f"worst case with no exchange at all: {self.limit:.4g} (above the axis)"
                else:
                    label = "worst case with no exchange at all"
                top.axhline(self.limit, color="C1", ls=(0, (1, 3)), lw=1, label=label)
            if self.wc is not None and self.wc.answer is not None:
                top.axvline(ax.value(self.wc.answer), color="C1", ls=":", lw=2,
                            label=f"worst-case answer {ax.value(self.wc.answer):g} ({self.wc.status})")
        p = self.paper
        if "error" not in p:
            dax = p.get("d_star_in_axis_units")
            if p["meaningful"] and dax is not None:
                top.axvline(dax, color="C4", ls="-.", lw=1.5, label=f"paper bound {dax:.3g}")
            txt = (f"paper bound, eq. (delay_bound): d_t <= {_fmt(p['d_star'])}"
                   + ("" if p["meaningful"] else " (meaningless)") +
                   f"\nit guarantees lambda_max(P) <= {_pow10(p['log10_lambda_max_bound']['0'])} at d_t = 0, "
                   f"{_pow10(p['log10_lambda_max_bound']['1'])} at d_t = 1")
            top.text(0.01, 0.98, txt, transform=top.transAxes, va="top", fontsize=7.5, color="C4",
                     bbox=dict(boxstyle="round", fc="white", ec="C4", alpha=0.85))
        top.set_ylabel(metric_label(st.metric, md.comp_name, md.sc))
        top.set_title(f"Largest {ax.name} within tolerance (point labels: Monte Carlo runs)", fontsize=10)
        top.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
        top.grid(alpha=0.3)
        # -- bottom: what the decisions use
        for c in cs:
            lo, hi = c.excess_ci
            top_err = [[c.excess_mean - lo], [hi - c.excess_mean]] if math.isfinite(lo) else None
            bot.errorbar([c.delay], [c.excess_mean], yerr=top_err, fmt="o", color=colours[c.decision],
                         ms=4, capsize=3)
        if ws and self.wc_tol is not None:
            bot.plot([c.delay for c in ws], [c.mean - self.wc_tol for c in ws], "s-", color="C1", ms=3,
                     lw=0.8, label="worst case minus its tolerance")
        bot.axhline(0.0, color="k", lw=1)
        bot.plot([], [], "o", color="0.3", label="Monte Carlo: mean and CI of " +
                 ("metric - tolerance" if st.relative is None else
                  f"metric_d[r] - {st.relative:g} metric_0[r] (paired runs)"))
        bot.set_ylabel("excess over tolerance\n(units of the metric)")
        bot.set_xlabel(axis_label(ax))
        bot.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
        bot.grid(alpha=0.3)
        if ax.mode == "d_t":
            bot.xaxis.set_major_locator(MaxNLocator(integer=True))
        fig.tight_layout()
        for ext in ("png", "pdf"):
            fig.savefig(out / f"maxdelay.{ext}", dpi=300)
        drawn = {"xlabel": bot.get_xlabel(), "ylabel": top.get_ylabel(),
                 "legend": [t.get_text() for a in (top, bot) for t in a.get_legend().get_texts()],
                 "texts": [t.get_text() for t in top.texts]}
        plt.close(fig)
        return drawn


def _double(v) -> str:
    return f"{2 * v:g}" if v else "8"


def _fmt(v) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float) and math.isinf(v):
        return "-inf" if v < 0 else "inf"
    return f"{v:.4g}"


def _answer_text(e: dict, unit: str, option: str = "--max-delay") -> str:
    s = e["status"]
    if s == "decided":
        return f"{unit} = {e['answer']:g} (decided: {unit} = {e['first_exceeding']:g} exceeds)"
    if s == "capped":
        return (f"{unit} >= {e['answer']:g} (capped: within tolerance up to the largest candidate "
                f"tried; raise it with {option}, e.g. {option} {_double(e['answer'])})")
    if s == "none":
        return "none: even zero delay exceeds the tolerance"
    a = "none" if e["answer"] is None else f"{e['answer']:g}"
    pe = "n/a" if e["point_estimate"] is None else f"{e['point_estimate']:g}"
    return f"{unit} = {a} (undecided: run cap hit near the boundary; by the means {pe})"

