"""The delay axis of ``dkfsim maxdelay``: how candidate ``j`` becomes a scenario.

``d_t`` of ``uniform_steps`` latency models, or a scale on every time parameter of
continuous ones; the worst-case (every link at its largest latency) and no-exchange
overrides.  See :mod:`dkfsim.experiments.maxdelay` and docs/design.md.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

from dkfsim.components.latency import LatencyParams, parse_latency
from dkfsim.config.load import load_scenario
from dkfsim.config.plan import RunPlan
from dkfsim.config.schema import Scenario
from dkfsim.core.errors import DkfsimError
from dkfsim.core.registry import LATENCY_MODELS

#: Random topology generators; maxdelay pins their seed so the graph is the same in every run.
RANDOM_GENERATORS = ("random_tree", "random_regular", "erdos_renyi")



# =========================================================================== delay axis
def _seconds(x: float) -> str:
    """Seconds rounded to whole nanoseconds, as YAML text that round-trips."""
    return repr(round(float(x) * 1e9) / 1e9)


def _const(seconds: float) -> str:
    return f"{{model: constant, value: {_seconds(seconds)}}}"


def _value_at(lat: dict, dotted: str):
    node = lat
    for part in dotted.split("."):
        node = node[part]
    return node


def _scaled_keys(path: str, lat: dict) -> list[str]:
    """The dotted keys (under ``path``) a latency scale multiplies, as the model declares
    them (:meth:`~dkfsim.components.latency.LatencyParams.scaled_keys`)."""
    keys = parse_latency(lat).scaled_keys()
    if keys is None:
        raise DkfsimError(f"{path}: latency model {lat['model']!r} cannot be scaled")  # excluded by make_axis
    return [f"{path}.{k}" for k in keys]


def _scale_overrides(path: str, lat: dict, s: float) -> list[str]:
    """Overrides multiplying every time parameter of the latency model at ``path`` by ``s``."""
    keys = parse_latency(lat).scaled_keys()
    if keys is None:
        raise DkfsimError(f"{path}: latency model {lat['model']!r} cannot be scaled")  # excluded by make_axis
    return [f"{path}.{k}={repr(float(_value_at(lat, k)) * s)}" for k in keys]


def _scalable(lat: dict) -> bool:
    return parse_latency(lat).scaled_keys() is not None


def _declares_scale(params: type | None) -> bool:
    assert params is not None and issubclass(params, LatencyParams)    # every latency model's params
    return params.scale_keys is not None or params.nests_models


def scalable_models() -> list[str]:
    """Latency models a scale can multiply (those declaring ``scale_keys``, or nesting models)."""
    return [e.name for e in LATENCY_MODELS.entries() if _declares_scale(e.params)]


@dataclass
class DelayAxis:
    """How a candidate index ``j`` becomes a scenario: ``--set`` overrides on ``base``.

    ``mode = "d_t"``: ``d_t = j`` on every ``uniform_steps`` latency model
    (and ``links.d_t = j`` when the scenario sets it).  ``mode = "scale"``:
    ``s = j * step``; every time parameter (as each model declares,
    nested models recursively) of every latency *and jitter*
    model is multiplied by ``s``; ``s = 0`` makes them ``constant 0``;
    ``links.d_t``, when set, becomes ``ceil(s * links.d_t)``.  Schedules (a
    factor on the latency over time) are left as they are.

    ``base`` is the scenario with every estimator but the measured one dropped and a random
    topology's seed pinned (so every run has the base scenario's graph).
    """

    mode: str
    step: float
    max_index: int
    base: Scenario
    specs: list                 # [(dotted path, latency dict), ...]: every latency model
    jitters: list               # [(dotted path, latency dict), ...]: every jitter model
    T: float
    T_ns: int
    steps: int
    links_d_t: int | None

    # ------------------------------------------------------------------ values
    def value(self, j: int):
        return int(j) if self.mode == "d_t" else round(j * self.step, 12)

    def label(self, j: int) -> str:
        return f"d_t = {j}" if self.mode == "d_t" else f"s = {self.value(j):g}"

    @property
    def name(self) -> str:
        return "d_t" if self.mode == "d_t" else "latency scale s"

    def _links_d_t(self, j: int) -> list[str]:
        if self.links_d_t is None:
            return []
        if self.mode == "d_t":
            return [f"links.d_t={j}"]
        return [f"links.d_t={self._scaled_d_t(j)}"]

    def _scaled_d_t(self, j: int) -> int:
        return math.ceil(self.value(j) * self.links_d_t - 1e-9)

    # ------------------------------------------------------------------ overrides
    def overrides(self, j: int) -> list[str]:
        """``--set`` overrides that turn ``base`` into candidate ``j``."""
        if self.mode == "d_t":
            return [f"{path}.d_t={j}" for path, _ in self.specs] + self._links_d_t(j)
        s = self.value(j)
        out = []
        for path, lat in self.specs + self.jitters:
            out += [f"{path}={_const(0.0)}"] if s == 0 else _scale_overrides(path, lat, s)
        return out + self._links_d_t(j)

    def sup_seconds(self, lat: dict, s: float) -> float | None:
        """Largest latency (s) of a model scaled by ``s``; ``None`` when unbounded."""
        sup = parse_latency(lat, self.base.base_dir).sup_ns(self.T_ns)
        return None if sup is None else s * sup / 1e9

    def worst_overrides(self, j: int) -> list[str] | None:
        """Every latency (and jitter) at its largest value, constant; ``None``
        when one is unbounded and there is no ``links.d_t`` to stand in."""
        out = []
        for path, lat in self.specs:
            sup: float | None
            if self.mode == "d_t":
                sup = j * self.T
            else:
                sup = self.sup_seconds(lat, self.value(j))
                if sup is None:
                    if self.links_d_t is None:
                        return None
                    sup = self._scaled_d_t(j) * self.T
            out.append(f"{path}={_const(sup)}")
        for path, lat in self.jitters:
            sup = self.sup_seconds(lat, 1.0 if self.mode == "d_t" else self.value(j))
            if sup is None:
                return None
            out.append(f"{path}={_const(sup)}")
        return out + self._links_d_t(j)

    def limit_overrides(self) -> list[str]:
        """No information ever arrives within the run (latency ``(K + 1) T``;
        a buffer of one row: nothing could fill a longer one)."""
        v = _const((self.steps + 1) * self.T)
        return [f"{path}={v}" for path, _ in self.specs] + \
            [f"{path}={_const(0.0)}" for path, _ in self.jitters] + ["buffer_length=1"]

    def scenario(self, j: int, overrides: list[str] | None = None):
            return load_scenario(self.base, overrides=self.overrides(j) if overrides is None else overrides)

    def describe(self) -> dict:
        if self.mode == "d_t":
            keys = [f"{path}.d_t" for path, _ in self.specs]
        else:
            keys = [k for path, lat in self.specs + self.jitters for k in _scaled_keys(path, lat)]
        if self.links_d_t is not None:
            keys.append("links.d_t" + ("" if self.mode == "d_t" else " (ceil(s * links.d_t))"))
        return {"mode": self.mode, "name": self.name, "step": self.step,
                "max": self.value(self.max_index), "keys": keys,
                "untouched": "schedules (time-varying factors) stay as they are" +
                             ("; jitter models stay as they are" if self.mode == "d_t" and self.jitters
                              else "")}


def search_base(scenario, keep: str | None):
    """The scenario every candidate rewrites: only the estimator named ``keep`` (the searched
    one, if listed) and a random topology's seed pinned (so every run has the same graph)."""
    data = scenario.to_dict()
    kept = [e for e in data.get("estimators", []) if (e.get("name") or e["kind"]) == keep]
    pin = ["estimators=" + json.dumps(kept)]
    top = data.get("topology", {})
    if top.get("generator") in RANDOM_GENERATORS and "seed" not in (top.get("params") or {}):
        pin.append(f"topology.params.seed={int(scenario.seed)}")
    return load_scenario(scenario, overrides=pin)


def make_axis(scenario, *, max_delay: int, scale_step: float, max_scale: float,
              keep: str | None = None) -> DelayAxis:
    """The delay axis of ``scenario`` (raises DkfsimError when it has none).  The base
    scenario keeps only the estimator named ``keep`` (the searched one, if listed)."""
    data = scenario.to_dict()
    base = search_base(scenario, keep)
    links = data.get("links", {})
    default = links.get("default", {})
    specs = [("links.default.latency", default.get("latency", {"model": "constant", "value": 0.0}))]
    jitters = [("links.default.jitter", default["jitter"])] if default.get("jitter") else []
    for i, ov in enumerate(links.get("overrides", []) or []):
        if ov.get("latency") is not None:
            specs.append((f"links.overrides.{i}.latency", ov["latency"]))
        if ov.get("jitter") is not None:
            jitters.append((f"links.overrides.{i}.jitter", ov["jitter"]))
    models = {lat["model"] for _, lat in specs}
    where = ", ".join(f"{p} = {lat['model']}" for p, lat in specs)
    for path, lat in specs:
        if lat["model"] != "uniform_steps" and not _scalable(lat):
            raise DkfsimError(
                f"{path}: latency model {lat['model']!r} is neither uniform_steps (whose d_t maxdelay "
                f"searches) nor scalable ({', '.join(scalable_models())}: maxdelay "
                "multiplies their time parameters by a scale s); use one of those models")
    if "uniform_steps" in models and len(models) > 1:
        raise DkfsimError(
            f"the latency models mix uniform_steps (integer steps, searched over d_t) with continuous "
            f"ones (searched over a scale) ({where}); maxdelay moves one delay axis: make every latency "
            "model uniform_steps, or every one continuous")
    mode = "d_t" if models == {"uniform_steps"} else "scale"
    if mode == "scale":
        for path, lat in jitters:
            if not _scalable(lat):
                raise DkfsimError(f"{path}: jitter model {lat['model']!r} cannot be scaled; use one of "
                                  f"{', '.join(scalable_models())}")
    if mode == "d_t":
        if max_delay < 1:
            raise DkfsimError(f"--max-delay: must be >= 1, got {max_delay}")
        J, step = int(max_delay), 1.0
    else:
        if not scale_step > 0 or not math.isfinite(scale_step):
            raise DkfsimError(f"--scale-step: must be a finite number > 0, got {scale_step}")
        if not (max_scale >= scale_step and math.isfinite(max_scale)):
            raise DkfsimError(f"--max-scale: must be a finite number >= --scale-step ({scale_step}), "
                              f"got {max_scale}")
        J, step = int(math.floor(max_scale / scale_step + 1e-9)), float(scale_step)
    return DelayAxis(mode=mode, step=step, max_index=J, base=base, specs=specs, jitters=jitters,
                     T=float(scenario.model.T), T_ns=int(scenario.T_ns), steps=int(scenario.steps),
                     links_d_t=links.get("d_t"))


def latencies_deterministic(sc) -> bool:
    """True when no random draw can change any covariance of a run of ``sc``:
    every used link has a constant latency (and jitter), no loss, no
    duplicates and no random background load, and every sensor is linear (its information does not depend
    on its measurement)."""
    if any(s.kind != "linear" for s in sc.sensors):
        return False
    for u, v in RunPlan.of(sc).exchange.arcs:
        spec = sc.link_spec(u, v)
        if spec.loss > 0 or (getattr(spec, "duplicate", 0.0) or 0.0) > 0:
            return False
        bg = getattr(spec, "background", None)         # (keyed by the seed: random per run)
        if bg is not None and (bg.arrivals == "poisson" or bg.sizes == "exponential"):
            return False
        for lat in (spec.latency, getattr(spec, "jitter", None)):
            if lat is not None and not lat.deterministic:
                return False
    return True

