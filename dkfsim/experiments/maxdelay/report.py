"""The result of ``dkfsim maxdelay``: ``maxdelay.json`` and the text table.

The figure is drawn by the report stage (:mod:`dkfsim.report.maxdelay`), with the plot
style every figure shares.

See :mod:`dkfsim.experiments.maxdelay` and docs/design.md.
"""

from __future__ import annotations

import math
from pathlib import Path

from dkfsim.config.dynamics import CA_UNITS
from dkfsim.config.load import scenario_hash
from dkfsim.core.folders import staged, write_json
from dkfsim.engine.results import versions
from dkfsim.experiments.maxdelay.search import (
    METRICS,
    SearchResult,
    interval,
    json_number,
    of_the_dkf,
    tracked_estimate,
)


def pow10_text(x) -> str:
    """``10**x`` as a plain number (``0.8812``, ``3.2e+05``), not ``10^-0.0549``."""
    try:
        x = float(x)
    except (TypeError, ValueError):
        return "n/a"
    if not math.isfinite(x) or abs(x) > 300:
        return f"10^{x:.3g}"
    return f"{10 ** x:.4g}"


def axis_label(ax) -> str:
    """The axis with its unit."""
    if ax.mode == "rate":
        return f"{ax.name} [bit/s] (log axis; rightmost: no rate limit)"
    return "delay bound d_t [ticks]" if ax.mode == "d_t" else "latency scale s [× the scenario's latencies]"


def cap_option(ax) -> str:
    """The option that moves the last candidate of the axis."""
    return {"d_t": "--max-delay", "rate": "--min-rate"}.get(ax.mode, "--max-scale")


def axis_unit(ax) -> str:
    """What a candidate's value is called in the table."""
    return {"d_t": "d_t", "rate": "rate"}.get(ax.mode, "s")


#: Candidate 0 of each axis (``--axis``): the reference of a relative tolerance.
REFERENCE = {"delay": "zero delay", "rate": "unlimited rate"}


def reference_words(ax) -> str:
    """Candidate 0 of ``ax`` ("paired with the same runs at zero delay")."""
    return REFERENCE["rate" if ax.mode == "rate" else "delay"]


def reference_name(ax) -> str:
    """Candidate 0 of ``ax`` as an adjective ("zero-delay value")."""
    return reference_words(ax).replace(" ", "-")


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
                 paper: dict, runs_empirical: int, runs_total: int, wall: float, rate_bound: dict | None = None):
        self.md, self.emp, self.wc, self.wc_tol, self.limit = md, emp, wc, wc_tol, limit
        #: the rate axis's lower bound from the packet sizes (:func:`~.rate.rate_lower_bound`)
        self.rate_bound = rate_bound
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
    def events(self) -> dict[str, int]:
        """The events of every run the search made, summed (what its estimate predicted)."""
        return self.md.events

    @property
    def answer(self):
        a = self.emp.answer
        return None if a is None else self.md.axis.value(a)

    def _search_dict(self, res: SearchResult, cands: dict) -> dict:
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
                          (" of the node estimates, mean over nodes" if tracked_estimate(st) == "local" else
                           " of the fused estimate"),
                "tolerance": self.wc_tol,
                "no_exchange_limit": self.limit,
                "never_exceeds": None if self.limit is None or self.wc_tol is None else
                bool(self.limit <= self.wc_tol)},
            "paper_bound": paper,
            **({"rate_lower_bound": self.rate_bound} if md.axis.mode == "rate" else {}),
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

    def save(self, out_dir, figure=None) -> Path:
        """Write ``maxdelay.json`` and, when ``figure`` is given, the figure it draws
        (``figure(result, stem)``; ``dkfsim maxdelay`` passes
        :func:`dkfsim.report.maxdelay.plot_maxdelay`, which writes ``stem.png`` and ``.pdf``);
        the folder is replaced atomically, figure included."""
        data = self.to_dict()
        with staged(out_dir, "maxdelay") as tmp:
            write_json(tmp / "maxdelay.json", data)
            if figure is not None:
                figure(self, tmp / "maxdelay")
        return Path(out_dir)

    # ------------------------------------------------------------------ text
    def table(self) -> str:
        md, st, ax = self.md, self.md.st, self.md.axis
        d = self.to_dict()
        unit = axis_unit(ax)
        tol = (f"<= {st.tolerance:g}" if st.relative is None else
               f"<= {st.relative:g} x {reference_name(ax)} value")
        lines = [f"{md.sc.name}: {'least' if ax.mode == 'rate' else 'largest'} {ax.name} with {st.metric}"
                 f"{'' if st.metric == 'trace_P' else ' (' + md.comp_name + ')'} {tol}, "
                 f"{100 * st.confidence:g}% confidence, {md.sc.steps} ticks, burn-in {md.burn}"]
        if self.reference:
            r = self.reference
            how = "deterministic" if r["deterministic"] else f"{r['runs']} runs"
            lines.append(f"  {reference_name(ax)} value {r['mean']:.4g} [{r['ci'][0]:.4g}, {r['ci'][1]:.4g}] "
                         f"({how}) -> tolerance {r['tolerance']:.4g} (each candidate decided on its runs "
                         f"paired with the same runs at {reference_words(ax)}: a mean a little "
                         "above this can be within)")
        e = d["empirical"]
        lines.append(f"  (1) empirical:   {_answer_text(e, unit, cap_option(ax), ax.mode)}  "
                     f"({self.runs_empirical} Monte Carlo runs)")
        for key, what in (("at_answer", "at answer"), ("at_answer_plus_1", "at answer+1")):
            a = e[key]
            if a:
                excess = "paired excess CI" if self.md.st.relative is not None else "excess over tolerance CI"
                lines.append(f"        {what:12s} {unit} = {a['delay']:g}: mean {a['mean']:.4g} "
                             f"CI [{a['ci'][0]:.4g}, {a['ci'][1]:.4g}]; {excess} "
                             f"[{a['excess_ci'][0]:+.3g}, {a['excess_ci'][1]:+.3g}]; {a['runs']} runs, "
                             f"{a['decision']}" + (" (on the paired excess)" if self.md.st.relative is not None
                                                  else ""))
        w = d["worst_case"]
        if ax.mode == "rate":
            lines.append("  (2) lower bound: " + _bound_text(self.rate_bound))
        elif w is None and not of_the_dkf(self.md.st):
            lines.append(f"  (2) worst case:  not computed (it follows the anti-delay DKF's covariance, "
                         f"not {self.md.st.estimate}'s)")
        elif w is None:
            lines.append("  (2) worst case:  not computed (unbounded latency without links.d_t)")
        else:
            lines.append(f"  (2) worst case:  {_answer_text(w, unit, cap_option(ax))}  (every link at its largest "
                         f"latency; tolerance {w['tolerance']:.4g}; no-exchange limit "
                         f"{w['no_exchange_limit']:.4g})")
        p = d["paper_bound"]
        if ax.mode == "rate":
            pass
        elif "error" in p:
            lines.append(f"  (3) paper bound: not computed: {p['error']}")
        else:
            ds = p["d_star"]
            lines.append(
                f"  (3) paper bound: d* = {number_text(ds)} -> "
                f"{'d_t <= %d' % p['d_t_bound'] if p['meaningful'] else 'MEANINGLESS (no delay guaranteed)'}; "
                f"terms: n = {p['n']}, "
                f"n_bar = {p['n_bar']}, Z = {p['Z']}, alpha_bar = {p['alpha_used']:.4g}, "
                f"eta = {p['eta']:.6g}, gamma_hat = {p['gamma_hat']:.4g}, omega_min = {p['omega_min']:.4g} "
                f"(literal {p['omega_min_literal']:.4g}), p_tol = {p['p_tol']:.4g}")
            lines.append(f"        p_tol: the level on lambda_max(P) the bound is solved for, from the "
                         f"covariance tolerance {p['covariance_tolerance']:.4g}: {p['p_tol_rule']}")
            lines.append(f"        guaranteed lambda_max(P) <= {pow10_text(p['log10_lambda_max_bound']['0'])} at "
                         f"d_t = 0, {pow10_text(p['log10_lambda_max_bound']['1'])} at d_t = 1, "
                         f"{pow10_text(p['log10_lambda_max_bound']['4'])} at d_t = 4")
            if p["note"]:
                lines.append(f"        {p['note']}")
        for n in d["notes"]:
            lines.append(f"  note: {n}")
        worst = self.runs_total - self.runs_empirical       # (none on the rate axis, or for another estimator)
        lines.append(f"  {self.runs_total} runs in {self.wall:.1f} s" + (
            f": {self.runs_empirical} Monte Carlo (1), {worst} deterministic for the worst case (2)" if worst else ""))
        return "\n".join(lines)


def _double(v) -> str:
    return f"{2 * v:g}" if v else "8"


def number_text(v) -> str:
    """A number of the table and the figure: 4 significant digits; None: "n/a"."""
    if v is None:
        return "n/a"
    if isinstance(v, float) and math.isinf(v):
        return "-inf" if v < 0 else "inf"
    return f"{v:.4g}"


def _bound_text(b: dict | None) -> str:
    """The rate axis's lower bound, one line."""
    if not b or "error" in b:
        return "not computed" + (f": {b['error']}" if b else "")
    u, v = b["link"]
    return (f"rate >= {b['rate']:.4g} bit/s (busiest link {u}->{v}: without a rate limit {b['estimate']} "
            f"puts {b['bytes_per_tick']:.4g} bytes in {b['packets_per_tick']:.3g} packets per tick on it, "
            f"{b['payload_bit_per_s']:.4g} bit/s without their headers, {b['own_bit_per_s']:.4g} with; "
            f"background {b['background_bit_per_s']:.4g} bit/s; below the bound utilisation > 1; "
            f"the traffic as sent without a limit fills the link at {b['demand_rate']:.4g} bit/s)")


def _answer_text(e: dict, unit: str, option: str = "--max-delay", mode: str = "d_t") -> str:
    """The empirical (or worst-case) answer, one line; on the rate axis the least rate."""
    s, rate = e["status"], mode == "rate"

    def fmt(v) -> str:
        return "none" if v is None else (f"{v:.4g} bit/s" if rate else f"{v:g}")
    if s == "decided":
        return f"{unit} = {fmt(e['answer'])} (decided: {unit} = {fmt(e['first_exceeding'])} exceeds)"
    if s == "capped" and rate:
        return (f"rate <= {fmt(e['answer'])} (capped: within tolerance down to the slowest candidate "
                f"tried; lower it with {option}, e.g. {option} {e['answer'] / 10:g})")
    if s == "capped":
        return (f"{unit} >= {e['answer']:g} (capped: within tolerance up to the largest candidate "
                f"tried; raise it with {option}, e.g. {option} {_double(e['answer'])})")
    if s == "none":
        return ("none: even without a rate limit the tolerance is exceeded" if rate else
                "none: even zero delay exceeds the tolerance")
    pe = "n/a" if e["point_estimate"] is None else fmt(e["point_estimate"])
    return f"{unit} = {fmt(e['answer'])} (undecided: run cap hit near the boundary; by the means {pe})"
