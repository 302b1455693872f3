"""Scenario schema: loading, every validation error, overrides, round trip, hash."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml
from pydantic import ValidationError

from dkfsim.components.estimators import EstimatorParams
from dkfsim.components.latency import Constant, Exponential, Uniform, UniformSteps
from dkfsim.config.load import load_scenario, scenario_hash
from dkfsim.config.plan import RunPlan
from dkfsim.config.schema import Scenario
from dkfsim.core.errors import ScenarioError
from dkfsim.core.registry import ESTIMATORS

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"

I3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]


def base() -> dict:
    """A small valid scenario: 4 sensors on a path, constant acceleration."""
    return {
        "name": "base",
        "seed": 2,
        "steps": 50,
        "model": {"kind": "constant_acceleration", "T": 0.01, "Q": copy.deepcopy(I3)},
        "prior": {"mean": [0.0, 0.0, 0.0], "cov": copy.deepcopy(I3)},
        "sensors": [
            {"name": "a", "H": [[1.0, 0.0, 0.0]], "R": [[0.8]]},
            {"name": "b", "H": [[0.0, 1.0, 0.0]], "R": [[1.0]]},
            {"name": "c", "H": [[0.0, 0.0, 1.0]], "R": [[2.0]]},
            {"name": "d", "H": [[1.0, 0.0, 0.0]], "R": [[0.5]]},
        ],
        "topology": {"generator": "path"},
        "links": {"default": {"latency": {"model": "uniform_steps", "d_t": 2}, "loss": 0.0}},
    }


def put(d: dict, dotted: str, value) -> dict:
    """Set ``dotted`` in ``d`` (test-side helper, independent of the override code)."""
    *parents, last = dotted.split(".")
    node = d
    for part in parents:
        node = node[int(part)] if isinstance(node, list) else node.setdefault(part, {})
    if isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return d


def write(tmp_path: Path, data, name: str = "case.yaml") -> Path:
    path = tmp_path / name
    if isinstance(data, str):
        path.write_text(data)
    else:
        path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def load_error(source, overrides=()) -> str:
    with pytest.raises(ScenarioError) as err:
        load_scenario(source, overrides)
    msg = str(err.value)
    assert "\n" not in msg, msg
    assert "pydantic" not in msg and "errors.pydantic.dev" not in msg, msg
    return msg


def expect(tmp_path, data, key, *reasons):
    """Writing ``data`` to a file and loading it fails with ``file: key: ...reasons``."""
    path = write(tmp_path, data)
    msg = load_error(path)
    assert msg.startswith(f"{path}: {key}: "), msg
    for reason in reasons:
        assert reason in msg, f"{reason!r} not in {msg!r}"
    return msg


# =========================================================================== valid input
def test_the_keys_example_of_the_docs_validates(tmp_path):
    """docs/scenarios.md's "The keys" block, pasted as a file, is a scenario (it named edges of
    three nodes with one sensor: "node 1 is out of range")."""
    import re
    text = (Path(__file__).resolve().parents[1] / "docs" / "scenarios.md").read_text()
    block = re.findall(r"```yaml\n(.*?)```", text, flags=re.S)[0]
    (tmp_path / "keys.yaml").write_text(block)
    sc = load_scenario(tmp_path / "keys.yaml")
    assert sc.n == 3 and sc.mobility is not None and sc.links.overrides


def test_base_loads_with_defaults():
    sc = load_scenario(base())
    assert sc.n == 4 and sc.nx == 3
    assert sc.links.overrides == () and sc.links.d_t is None
    assert sc.protocol == "tree" and sc.weights == "unit" and sc.spanning_tree is False
    assert sc.buffer_length == "auto" and sc.fusion == "matrix"
    assert tuple(p.kind for p in sc.estimators) == ("centralized",)
    assert tuple(p.label for p in sc.estimators) == ("centralized",)
    assert sc.topology.directed is False


def test_minimal_defaults():
    d = base()
    for key in ("name", "seed", "steps", "links"):
        del d[key]
    sc = load_scenario(d)
    assert sc.seed == 0 and sc.steps == 1000
    spec = sc.link_spec(0, 1)
    assert isinstance(spec.latency, Constant) and spec.latency.value == 0.0
    assert spec.loss == 0.0
    assert RunPlan(sc).buffer_length() == 1  # d_t = 0 -> L = 0 * d_g + 1


def test_name_defaults_to_file_stem(tmp_path):
    d = base()
    del d["name"]
    assert load_scenario(write(tmp_path, d, "my_case.yaml")).name == "my_case"


def test_matrix_accessors():
    sc = load_scenario(base())
    T = 0.01
    np.testing.assert_array_equal(sc.model.Phi_matrix(),
                                  [[1, T, T * T / 2], [0, 1, T], [0, 0, 1]])
    assert sc.model.Q_matrix().shape == (3, 3)
    assert sc.prior.mean_vector().shape == (3,)
    assert sc.prior.cov_matrix().shape == (3, 3)
    s = sc.sensors[2]
    assert s.name == "c"
    assert s.H_matrix().shape == (1, 3) and s.R_matrix().shape == (1, 1)
    assert s.R_matrix()[0, 0] == 2.0
    assert isinstance(sc.model.Phi_matrix(), np.ndarray)


def test_linear_model():
    d = base()
    d["model"] = {"kind": "linear", "T": 0.5, "Phi": [[1, 0.5], [0, 1]], "Q": [[0.1, 0], [0, 0]]}
    d["prior"] = {"mean": [0, 0], "cov": [[1, 0], [0, 1]]}
    for s in d["sensors"]:
        s["H"] = [[1, 0]]
    sc = load_scenario(d)
    assert sc.nx == 2
    np.testing.assert_array_equal(sc.model.Phi_matrix(), [[1, 0.5], [0, 1]])
    assert sc.T_ns == 500_000_000


def test_scalar_R_flat_H_and_vectors():
    d = base()
    d["sensors"][0] = {"name": "a", "H": [1, 0, 0], "R": 0.8}
    d["prior"]["mean"] = [[1], [2], [3]]  # a column is flattened
    sc = load_scenario(d)
    np.testing.assert_array_equal(sc.sensors[0].H_matrix(), [[1, 0, 0]])
    np.testing.assert_array_equal(sc.sensors[0].R_matrix(), [[0.8]])
    np.testing.assert_array_equal(sc.prior.mean_vector(), [1, 2, 3])


def test_multi_row_sensor():
    d = base()
    d["sensors"][1] = {"name": "b", "H": [[1, 0, 0], [0, 1, 0]], "R": [[1, 0.3], [0.3, 2]]}
    sc = load_scenario(d)
    assert sc.sensors[1].R_matrix().shape == (2, 2)


def test_Q_may_be_singular():
    d = put(base(), "model.Q", [[0, 0, 0], [0, 0, 0], [0, 0, 1]])
    assert load_scenario(d).model.Q_matrix()[2, 2] == 1.0


@pytest.mark.parametrize("T, ns", [(0.01, 10_000_000), (0.001, 1_000_000), (1e-9, 1),
                                   (2, 2_000_000_000), (0.1, 100_000_000)])
def test_T_ns(T, ns):
    sc = load_scenario(put(base(), "model.T", T))
    assert sc.T_ns == ns and isinstance(sc.T_ns, int)


def test_exponent_floats_in_yaml(tmp_path):
    text = yaml.safe_dump(base(), sort_keys=False).replace("T: 0.01", "T: 1e-2")
    assert "T: 1e-2" in text
    assert load_scenario(write(tmp_path, text)).model.T == 0.01


@pytest.mark.parametrize("name", ["paper_case1.yaml", "paper_case2.yaml"])
def test_paper_scenarios(name):
    sc = load_scenario(SCENARIOS / name)
    assert sc.n == 12 and sc.nx == 3 and sc.steps == 1000 and sc.seed == 1
    assert [s.name for s in sc.sensors] == [f"s{i}" for i in range(1, 13)]
    R = [0.8, 1.0, 2.0, 1.0, 0.5, 1.5, 1.0, 1.0, 0.1, 1.0, 1.5, 1.0]
    assert [s.R_matrix()[0, 0] for s in sc.sensors] == R
    for i, s in enumerate(sc.sensors):
        np.testing.assert_array_equal(s.H_matrix(), np.eye(3)[[i % 3]])
    assert sc.link_spec(0, 1).latency == UniformSteps(d_t=4)
    assert sc.weights == "unit"
    if name == "paper_case1.yaml":
        assert sc.protocol == "tree" and not sc.topology.directed
        assert RunPlan(sc).buffer_length() == 4 * 4 + 1
    else:
        assert sc.protocol == "flood" and sc.topology.directed
        assert RunPlan(sc).buffer_length() == 4 * 5 + 1


# =========================================================================== file errors
def test_file_not_found(tmp_path):
    path = tmp_path / "missing.yaml"
    msg = load_error(path)
    assert msg == f"{path}: file not found"


def test_yaml_syntax_error_has_line(tmp_path):
    path = write(tmp_path, "name: x\nseed: 1\nsteps: [1, 2\nmodel: {}\n")
    msg = load_error(path)
    assert msg.startswith(f"{path}: ")
    assert "YAML syntax error" in msg and "line 3" in msg


def test_yaml_syntax_error_mapping(tmp_path):
    path = write(tmp_path, "name: x\nseed: 1\nsteps: a: b\n")
    msg = load_error(path)
    assert "line 3" in msg and str(path) in msg


def test_duplicate_yaml_key(tmp_path):
    path = write(tmp_path, "name: x\nseed: 1\nseed: 2\n")
    msg = load_error(path)
    assert str(path) in msg and "duplicate key 'seed'" in msg and "line 3" in msg


@pytest.mark.parametrize("text, what", [("- 1\n- 2\n", "list"), ("just a string\n", "str"),
                                        ("42\n", "int")])
def test_top_level_not_a_mapping(tmp_path, text, what):
    path = write(tmp_path, text)
    msg = load_error(path)
    assert msg == f"{path}: top level must be a mapping of scenario keys, got {what}"


def test_empty_file(tmp_path):
    path = write(tmp_path, "")
    assert "empty file" in load_error(path)


def test_dict_source_is_named():
    msg = load_error(put(base(), "steps", 0))
    assert msg.startswith("<dict>: steps: ")


# =========================================================================== value errors
@pytest.mark.parametrize("dotted, value, key, reasons", [
    # covariance matrices
    ("sensors.2.R", [[-0.2]], "sensors.2.R",
     ["not symmetric positive definite", "min eigenvalue -0.2"]),
    ("sensors.1.R", -1.0, "sensors.1.R", ["not symmetric positive definite"]),
    ("sensors.0.R", [[0.0]], "sensors.0.R", ["not symmetric positive definite",
                                             "min eigenvalue 0"]),
    ("sensors.3", {"name": "d", "H": [[1, 0, 0], [0, 1, 0]], "R": [[1, 0.5], [0.2, 1]]},
     "sensors.3.R", ["not symmetric"]),
    ("model.Q", [[1, 0, 0], [0, -1, 0], [0, 0, 1]], "model.Q",
     ["not symmetric positive semidefinite", "min eigenvalue -1"]),
    ("model.Q", [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]], "model.Q", ["not symmetric"]),
    ("prior.cov", [[1, 0, 0], [0, 0, 0], [0, 0, 1]], "prior.cov",
     ["not symmetric positive definite"]),
    ("prior.cov", [[1, 2, 0], [2, 1, 0], [0, 0, 1]], "prior.cov",
     ["not symmetric positive definite", "min eigenvalue -1"]),
    # shapes
    ("sensors.1.H", [[1, 0]], "sensors.1.H", ["3 columns", "1 x 2"]),
    ("sensors.1.R", [[1, 0], [0, 1]], "sensors.1.R", ["1 x 1", "2 x 2"]),
    ("model.Q", [[1, 0], [0, 1]], "model.Q", ["3 x 3", "2 x 2"]),
    ("model.Q", [[1, 0, 0], [0, 1], [0, 0, 1]], "model.Q", ["rows have different lengths"]),
    ("prior.mean", [0, 0], "prior.mean", ["2 entries", "3 x 3"]),
    ("prior", {"mean": [0, 0], "cov": [[1, 0], [0, 1]]}, "prior.mean",
     ["2 entries", "state has 3"]),
    ("model", {"kind": "linear", "T": 0.01, "Phi": [[1, 0, 0], [0, 1, 0]], "Q": I3},
     "model.Phi", ["must be square", "2 x 3"]),
    ("model", {"kind": "linear", "T": 0.01, "Q": I3}, "model.Phi", ["required"]),
    ("model.Phi", I3, "model.Phi", ["constant_acceleration"]),
    ("sensors.0.H", [["x", 0, 0]], "sensors.0.H", ["must be numbers", "'x'"]),
    ("sensors.0.R", float("nan"), "sensors.0.R", ["finite"]),
    # scalars
    ("model.T", 0.0, "model.T", ["must be > 0"]),
    ("model.T", -0.01, "model.T", ["must be > 0", "-0.01"]),
    ("model.T", 1.5e-9, "model.T", ["whole number of nanoseconds", "1.5 ns"]),
    ("model.T", 0.0100000001, "model.T", ["whole number of nanoseconds"]),
    ("steps", 0, "steps", ["must be >= 1", "got 0"]),
    ("steps", 2.5, "steps", ["must be an integer"]),
    ("seed", -1, "seed", ["must be >= 0"]),
    ("links.default.loss", 1.5, "links.default.loss", ["must be <= 1", "1.5"]),
    ("links.default.loss", -0.1, "links.default.loss", ["must be >= 0", "-0.1"]),
    ("links.overrides", [{"link": [0, 1], "loss": 2.0}], "links.overrides.0.loss",
     ["must be <= 1"]),
    ("links.default.latency", {"model": "constant", "value": -0.02},
     "links.default.latency.value", ["must be >= 0", "-0.02"]),
    ("links.default.latency", {"model": "uniform_steps", "d_t": -1},
     "links.default.latency.d_t", ["must be >= 0"]),
    ("links.default.latency", {"model": "uniform", "low": -0.01, "high": 0.01},
     "links.default.latency.low", ["must be >= 0"]),
    ("links.default.latency", {"model": "uniform", "low": 0.02, "high": 0.01},
     "links.default.latency.high", ["must be >= low"]),
    ("links.default.latency", {"model": "exponential", "mean": -1.0},
     "links.default.latency.mean", ["must be > 0"]),
    ("links.overrides", [{"link": [0, 1], "latency": {"model": "constant", "value": -1.0}}],
     "links.overrides.0.latency.value", ["must be >= 0"]),
    ("links.d_t", -2, "links.d_t", ["must be >= 0"]),
    ("buffer_length", 0, "buffer_length", ["'auto', 'paper' or an integer >= 1"]),
    ("buffer_length", "papr", "buffer_length", ["did you mean 'paper'?"]),
    ("topology.directed", "yes", "topology.directed", ["true or false"]),
    ("sensors", [], "sensors", ["at least one sensor"]),
    ("sensors.1.name", "a", "sensors.1.name", ["already the name of sensors.0"]),
    ("sensors.0", [1, 2], "sensors.0", ["must be a mapping"]),
    ("baselines", ["centralised"], "baselines.0",
     ["unknown estimator 'centralised'", "did you mean 'centralized'?", "centralized"]),
    ("baselines", ["centralized", "centralized"], "baselines.1", ["listed twice"]),
])
def test_bad_values(tmp_path, dotted, value, key, reasons):
    expect(tmp_path, put(base(), dotted, value), key, *reasons)


def test_missing_required_key(tmp_path):
    d = base()
    del d["prior"]
    expect(tmp_path, d, "prior", "required key is missing")


# =========================================================================== unknown keys/names
@pytest.mark.parametrize("dotted, key, suggestion", [
    ("buffer_lenght", "buffer_lenght", "buffer_length"),
    ("protocl", "protocl", "protocol"),
    ("sensors.0.Rr", "sensors.0.Rr", "R"),
    ("model.phi", "model.phi", "Phi"),
    ("topology.generatr", "topology.generatr", "generator"),
    ("links.default.los", "links.default.los", "loss"),
    ("links.default.latency.dt", "links.default.latency.dt", "d_t"),
    ("links.dt", "links.dt", "d_t"),
    ("prior.conv", "prior.conv", "cov"),
])
def test_unknown_key_suggests(tmp_path, dotted, key, suggestion):
    expect(tmp_path, put(base(), dotted, 3), key, "unknown key",
           f"did you mean '{suggestion}'?")


def test_unknown_key_without_close_match_lists_allowed(tmp_path):
    msg = expect(tmp_path, put(base(), "zzzz", 1), "zzzz", "unknown key", "allowed keys:")
    assert "buffer_length" in msg


def test_unknown_latency_model(tmp_path):
    expect(tmp_path, put(base(), "links.default.latency", {"model": "gausian", "mean": 1}),
           "links.default.latency.model", "unknown latency model 'gausian'",
           "constant, uniform_steps, uniform, exponential")


def test_latency_without_model(tmp_path):
    expect(tmp_path, put(base(), "links.default.latency", {"d_t": 1}),
           "links.default.latency", "missing key 'model'", "uniform_steps")


def test_unknown_generator(tmp_path):
    expect(tmp_path, put(base(), "topology.generator", "balanced_tre"), "topology.generator",
           "unknown graph generator 'balanced_tre'", "did you mean 'balanced_tree'?",
           "path, star, balanced_tree, random_tree, ring, random_regular, erdos_renyi, edges")


def test_unknown_protocol(tmp_path):
    expect(tmp_path, put(base(), "protocol", "gossip"), "protocol",
           "unknown protocol 'gossip'", "tree, flood")


def test_unknown_fusion_and_weights(tmp_path):
    expect(tmp_path, put(base(), "fusion", "average"), "fusion", "matrix, diagonal, none")
    expect(tmp_path, put(base(), "weights", "metropolis"), "weights", "unit, paper")


def test_unknown_model_kind(tmp_path):
    expect(tmp_path, put(base(), "model.kind", "ca"), "model.kind",
           "unknown model kind 'ca'", "constant_acceleration, constant_velocity, linear")


def test_unknown_generator_param(tmp_path):
    d = put(base(), "topology", {"generator": "random_tree", "params": {"sed": 3}})
    expect(tmp_path, d, "topology.params.sed", "unknown parameter", "did you mean 'seed'?")


def test_missing_generator_param(tmp_path):
    d = put(base(), "topology", {"generator": "random_regular", "params": {"seed": 3}})
    expect(tmp_path, d, "topology.params.d", "required")


# =========================================================================== graph errors
def test_disconnected_undirected(tmp_path):
    d = put(base(), "topology", {"generator": "edges", "edges": [[0, 1], [2, 3]]})
    expect(tmp_path, d, "topology", "disconnected", "2 components")


def test_directed_not_strongly_connected(tmp_path):
    d = put(base(), "topology", {"directed": True, "generator": "edges",
                                 "edges": [[0, 1], [1, 2], [2, 3], [3, 2], [2, 1]]})
    d["protocol"] = "flood"
    expect(tmp_path, d, "topology", "not strongly connected", "cannot reach node 0")


def test_tree_on_graph_with_cycles(tmp_path):
    d = put(base(), "topology", {"generator": "ring"})
    expect(tmp_path, d, "protocol", "cycles", "spanning_tree: true", "flood")
    d["spanning_tree"] = True
    assert RunPlan(load_scenario(d)).exchange.d_g <= 2 * 2


def test_tree_on_directed_graph(tmp_path):
    d = put(base(), "topology", {"directed": True, "generator": "ring"})
    expect(tmp_path, d, "protocol", "undirected", "use protocol: flood")
    d["protocol"] = "flood"
    assert RunPlan(load_scenario(d)).exchange.d_g == 3


def test_paper_weights_with_flood(tmp_path):
    d = base()
    d.update(protocol="flood", weights="paper")
    expect(tmp_path, d, "weights", "not defined", "flood")


def test_spanning_tree_on_directed(tmp_path):
    d = put(base(), "topology", {"directed": True, "generator": "ring"})
    d.update(protocol="flood", spanning_tree=True)
    expect(tmp_path, d, "spanning_tree", "undirected")


def test_edges_outside_node_range(tmp_path):
    d = put(base(), "topology", {"generator": "edges", "edges": [[0, 1], [1, 2], [2, 4]]})
    expect(tmp_path, d, "topology.edges.2", "node 4 is out of range 0..3", "4 sensors")


def test_edges_with_other_generator(tmp_path):
    d = put(base(), "topology.edges", [[0, 1]])
    expect(tmp_path, d, "topology.edges", "only used with generator: edges")


def test_generator_node_count_mismatch(tmp_path):
    d = base()
    d["sensors"] = [{"name": f"s{i}", "H": [[1, 0, 0]], "R": [[1.0]]} for i in range(12)]
    d["topology"] = {"generator": "balanced_tree", "params": {"r": 3, "h": 2}}
    expect(tmp_path, d, "topology.params", "13 nodes", "12 sensors")
    d["sensors"].append({"name": "s12", "H": [[1, 0, 0]], "R": [[1.0]]})
    assert load_scenario(d).n == 13


def test_override_link_not_an_edge(tmp_path):
    d = put(base(), "links.overrides", [{"link": [0, 1], "loss": 0.1},
                                        {"link": [0, 2], "loss": 0.1}])
    expect(tmp_path, d, "links.overrides.1.link", "[0, 2] is not an edge of the topology")


def test_override_link_outside_range(tmp_path):
    d = put(base(), "links.overrides", [{"link": [3, 9]}])
    expect(tmp_path, d, "links.overrides.0.link", "node 9 is out of range")


def test_auto_buffer_with_unbounded_latency(tmp_path):
    d = put(base(), "links.default.latency", {"model": "exponential", "mean": 0.01})
    expect(tmp_path, d, "buffer_length", "unbounded", "links.d_t", "buffer_length")
    expect(tmp_path, put(copy.deepcopy(d), "buffer_length", "paper"), "buffer_length",
           "links.d_t")
    assert RunPlan(load_scenario(put(copy.deepcopy(d), "links.d_t", 3))).buffer_length() \
        == 3 * 3 + 1
    assert RunPlan(load_scenario(put(copy.deepcopy(d), "buffer_length", 7))).buffer_length() == 7


def test_unbounded_override_alone_also_needs_bound(tmp_path):
    d = put(base(), "links.overrides",
            [{"link": [2, 3], "latency": {"model": "exponential", "mean": 0.01}}])
    expect(tmp_path, d, "buffer_length", "exponential")


# =========================================================================== overrides
def test_overrides_parse_yaml_values():
    sc = load_scenario(base(), ["seed=3", "links.default.loss=0.5", "protocol=flood",
                                "baselines=[]", "links.d_t=5", "sensors.0.R=[[2.0]]",
                                "links.default.latency.d_t=0", "name=with=equals",
                                "buffer_length=4"])
    assert sc.seed == 3 and sc.links.default.loss == 0.5 and sc.protocol == "flood"
    assert sc.estimators == () and sc.links.d_t == 5
    assert sc.sensors[0].R_matrix()[0, 0] == 2.0
    assert sc.link_spec(0, 1).latency == UniformSteps(d_t=0)
    assert sc.name == "with=equals" and sc.buffer_length == 4


def test_override_null_and_created_mappings():
    d = base()
    del d["links"]
    sc = load_scenario(d, ["links.d_t=5", "links.default.latency.model=uniform_steps",
                           "links.default.latency.d_t=1"])
    assert sc.links.d_t == 5 and sc.link_spec(1, 2).latency == UniformSteps(d_t=1)
    assert load_scenario(base(), ["links.d_t=null"]).links.d_t is None


def test_override_does_not_mutate_input():
    d = base()
    before = copy.deepcopy(d)
    load_scenario(d, ["seed=9", "sensors.1.R=3.0"])
    assert d == before


def test_override_from_file(tmp_path):
    path = write(tmp_path, base())
    sc = load_scenario(str(path), ["steps=7"])
    assert sc.steps == 7 and sc.source == str(path)


def test_override_on_scenario_object():
    sc = load_scenario(base())
    sc2 = load_scenario(sc, ["seed=11"])
    assert sc2.seed == 11 and sc.seed == 2


def test_bad_override_syntax(tmp_path):
    path = write(tmp_path, base())
    msg = load_error(path, ["seed3"])
    assert msg.startswith(f"{path}: ") and "'seed3'" in msg and "dotted.key=value" in msg


@pytest.mark.parametrize("override, key, reason", [
    ("sensors.9.R=1", "sensors.9", "list index 9 out of range"),
    ("sensors.-1.R=1", "sensors.-1", "list index -1 out of range"),
    ("sensors.x.R=1", "sensors.x", "not an index"),
    ("seed.value=1", "seed.value", "scalar"),
    ("model.T.x=1", "model.T.x", "scalar"),
])
def test_bad_override_path(tmp_path, override, key, reason):
    path = write(tmp_path, base())
    msg = load_error(path, [override])
    assert msg.startswith(f"{path}: {key}: "), msg
    assert reason in msg and override in msg


def test_unknown_override_key(tmp_path):
    path = write(tmp_path, base())
    msg = load_error(path, ["buffer_lenght=3"])
    assert msg.startswith(f"{path}: buffer_lenght: unknown key"), msg
    assert "did you mean 'buffer_length'?" in msg and "override 'buffer_lenght=3'" in msg


def test_invalid_override_value_names_override(tmp_path):
    path = write(tmp_path, base())
    msg = load_error(path, ["links.default.loss=2"])
    assert msg.startswith(f"{path}: links.default.loss: ") and "override" in msg


@pytest.mark.parametrize("overrides, cited", [
    (["links.default={loss: 0.5}", "links.default.loss=2"], "links.default.loss=2"),
    (["links.default.loss=0.5", "links.default={loss: 2}"], "links.default={loss: 2}"),
    (["links.default.loss=3", "links.default={loss: 0.5}", "links.default.loss=2"], "links.default.loss=2"),
    (["links.default={loss: 3}", "links.default.loss=0.5", "links.default={loss: 2}"], "links.default={loss: 2}"),
])
def test_the_note_cites_the_override_that_set_the_value(overrides, cited):
    """The last override applied at the key or above it set it: not the first that touched
    a mapping above it (medium.access={kind: sps} was cited for medium.access.subchannels=101)."""
    msg = load_error(base(), overrides)
    assert "links.default.loss: " in msg and msg.count("override") == 1 and f"(set by override '{cited}')" in msg, msg


# =========================================================================== link specs
def test_link_spec_takes_the_links_one_override():
    """A link has one override (issue 30 §7: a second one of the same link, or of its reverse on
    an undirected topology, is refused); it replaces the keys it gives, both ways."""
    d = put(base(), "links.overrides", [
        {"link": [1, 0], "latency": {"model": "constant", "value": 0.03}, "loss": 0.25},
        {"link": [1, 2], "latency": {"model": "uniform", "low": 0.0, "high": 0.031}},
    ])
    sc = load_scenario(d)
    # undirected: [1, 0] also matches 0 -> 1
    assert sc.link_spec(0, 1).latency == Constant(value=0.03)
    assert sc.link_spec(0, 1).loss == 0.25
    assert sc.link_spec(1, 0).latency == Constant(value=0.03)
    assert sc.link_spec(2, 1).latency == Uniform(low=0.0, high=0.031)
    assert sc.link_spec(2, 1).loss == 0.0
    assert sc.link_spec(2, 3).latency == UniformSteps(d_t=2)
    assert RunPlan(sc).d_t == 4  # ceil(0.031 / 0.01)
    d["links"]["overrides"].append({"link": [0, 1], "loss": 0.5})
    with pytest.raises(ScenarioError, match=r"links\.overrides\.2\.link: link \[0, 1\] already has an override"):
        load_scenario(d)


def test_link_spec_directed_matches_one_way():
    d = put(base(), "topology", {"directed": True, "generator": "ring"})
    d["protocol"] = "flood"
    d["links"]["overrides"] = [{"link": [0, 1], "latency": {"model": "constant", "value": 0.02}}]
    sc = load_scenario(d)
    assert sc.link_spec(0, 1).latency == Constant(value=0.02)
    assert sc.link_spec(1, 0).latency == UniformSteps(d_t=2)


def test_links_d_t_is_used_when_given():
    sc = load_scenario(base(), ["links.d_t=1"])
    assert RunPlan(sc).d_t == 1 and RunPlan(sc).buffer_length() == 1 * 3 + 1
    sc = load_scenario(base(), ["buffer_length=paper"])
    assert RunPlan(sc).buffer_length() == 2
    sc = load_scenario(base(), ["buffer_length=paper", "links.default.latency.d_t=0"])
    assert RunPlan(sc).buffer_length() == 1


def test_exponential_scenario_with_d_t():
    sc = load_scenario(base(), ["links.default.latency={model: exponential, mean: 0.01}",
                                "links.d_t=2"])
    assert isinstance(sc.link_spec(0, 1).latency, Exponential)
    assert RunPlan(sc).buffer_length() == 2 * 3 + 1


# =========================================================================== identity
def full_featured() -> dict:
    d = base()
    d["model"] = {"kind": "linear", "T": 0.02, "Phi": [[1, 0.02, 0], [0, 1, 0.02], [0, 0, 1]],
                  "Q": [[0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.0]]}
    d["topology"] = {"generator": "random_regular", "params": {"d": 2, "seed": 5}}
    d["links"] = {"default": {"latency": {"model": "uniform", "low": 0.001, "high": 0.05},
                              "loss": 0.1},
                  "overrides": [{"link": [0, 1], "loss": 0.5},
                                {"link": [2, 3],
                                 "latency": {"model": "exponential", "mean": 0.01}}],
                  "d_t": 6}
    d.update(protocol="flood", buffer_length=9, fusion="diagonal", baselines=[],
             spanning_tree=True)
    return d


@pytest.mark.parametrize("make", [base, full_featured,
                                  lambda: yaml.safe_load((SCENARIOS / "paper_case1.yaml")
                                                         .read_text()),
                                  lambda: yaml.safe_load((SCENARIOS / "paper_case2.yaml")
                                                         .read_text())])
def test_round_trip(tmp_path, make):
    sc = load_scenario(make())
    d = sc.to_dict()
    text = yaml.safe_dump(d, sort_keys=False)
    again = load_scenario(write(tmp_path, text, "again.yaml"))
    assert again == sc
    assert again.to_dict() == d
    assert scenario_hash(again) == scenario_hash(sc)
    assert again.link_spec(0, 1) == sc.link_spec(0, 1)
    assert "source" not in d


def test_to_dict_is_plain_data():
    d = load_scenario(full_featured()).to_dict()

    def check(x):
        if isinstance(x, dict):
            assert all(isinstance(k, str) for k in x)
            for v in x.values():
                check(v)
        elif isinstance(x, list):
            for v in x:
                check(v)
        else:
            assert x is None or isinstance(x, (str, int, float, bool)), type(x)

    check(d)


def test_hash():
    a = load_scenario(base())
    h = scenario_hash(a)
    assert len(h) == 64 and int(h, 16) >= 0
    assert scenario_hash(load_scenario(base())) == h
    assert scenario_hash(load_scenario(base(), ["seed=3"])) != h
    assert scenario_hash(load_scenario(base(), ["sensors.0.R=0.81"])) != h


def test_source_not_in_hash_or_equality(tmp_path):
    path = write(tmp_path, base())
    from_file = load_scenario(path)
    from_dict = load_scenario(base())
    assert from_file.source == str(path) and from_dict.source is None
    assert from_file == from_dict
    assert scenario_hash(from_file) == scenario_hash(from_dict)


def test_scenario_is_frozen():
    sc = load_scenario(base())
    with pytest.raises(ValidationError, match="frozen"):
        sc.seed = 5
    with pytest.raises(ValidationError, match="frozen"):
        sc.model.T = 0.1
    with pytest.raises(TypeError):
        sc.sensors[0].R[0] = (3.0,)


def test_errors_are_scenario_errors_never_pydantic():
    # a grab bag of broken inputs: every one must be a one-line ScenarioError
    broken = [put(base(), "model", 3), put(base(), "sensors", {"a": 1}),
              put(base(), "topology", None), put(base(), "links.overrides", [{"link": [0]}]),
              put(base(), "links.default.latency", "fast"), put(base(), "sensors.0.H", None),
              put(base(), "prior.mean", {"x": 1}), put(base(), "topology.params", [1, 2])]
    for d in broken:
        msg = load_error(d)
        assert msg.startswith("<dict>: ")


def test_estimator_registry_is_the_one_extension_point():
    import dkfsim.estimators  # noqa: F401  (registers the built-in implementations)
    from dkfsim.estimators.base import Estimator
    from dkfsim.estimators.centralized import Centralized

    assert "centralized" in ESTIMATORS and "kalman_oracle" not in ESTIMATORS
    d = put(base(), "baselines", ["centralized", "kalman_oracle"])
    assert "unknown estimator 'kalman_oracle'" in load_error(d)
    e = put(base(), "estimators", [{"kind": "centralized"}, {"kind": "kalman_oracle"}])
    assert "unknown estimator 'kalman_oracle'" in load_error(e)

    try:
        # One declaration: the kind once, as a class keyword; the implementation names its model.
        class KalmanOracleParams(EstimatorParams, kind="kalman_oracle"):
            """A test-only estimator."""

        class KalmanOracle(Centralized, params=KalmanOracleParams):
            pass

        entry = ESTIMATORS.get("kalman_oracle")
        assert (entry.params, entry.implementation) == (KalmanOracleParams, KalmanOracle)
        assert entry.description == "A test-only estimator"
        assert KalmanOracleParams().kind == "kalman_oracle" and KalmanOracle.Params is KalmanOracleParams
        with pytest.raises(ValidationError):
            KalmanOracleParams(kind="centralized")           # the kind is a literal
        for sc in (load_scenario(d), load_scenario(e)):
            assert tuple(p.kind for p in sc.estimators) == ("centralized", "kalman_oracle")
            assert isinstance(sc.estimators[1], KalmanOracleParams)
    finally:
        ESTIMATORS._entries.pop("kalman_oracle", None)
    assert "kalman_oracle" not in ESTIMATORS
    assert "unknown estimator 'kalman_oracle'" in load_error(d)
    # Every estimator a scenario may name has an implementation (and its own parameter
    # model), and every implementation is reachable from a scenario.
    assert ESTIMATORS.names()
    for entry in ESTIMATORS.entries():
        assert entry.params is not None and issubclass(entry.params, EstimatorParams), entry.name
        assert entry.implementation is not None, entry.name
        assert issubclass(entry.implementation, Estimator), entry.name
        assert entry.implementation.Params is entry.params, entry.name
        required = {"fusion_centre": {"at": 0}}.get(entry.name, {})     # keys without a default
        assert load_scenario(put(base(), "estimators", [{"kind": entry.name, **required}])).estimators[0].kind \
            == entry.name
    assert ESTIMATORS.canonical("local") == "local_only"


def test_scenario_model_validate_without_loader():
    sc = Scenario.model_validate(base())
    assert sc.n == 4 and sc.source is None


def test_consensus_rounds_must_divide_the_period():
    d = put(put(base(), "baselines", ["ci_consensus"]), "consensus_rounds", 3)
    d["model"]["T"] = 0.01
    msg = load_error(d)
    assert msg.startswith("<dict>: estimators.0.rounds: "), msg
    assert "consensus_rounds" in msg and "do not divide" in msg
    d["consensus_rounds"] = 4
    (ci,) = [p for p in load_scenario(d).estimators if p.kind == "ci_consensus"]
    assert ci.rounds == 4


def kinds_and_names(sc) -> list[tuple[str, str]]:
    return [(p.kind, p.label) for p in sc.estimators]


def test_the_older_baselines_spelling_is_the_same_scenario():
    old = put(put(base(), "baselines", ["centralized", "local", "ci_consensus"]), "consensus_rounds", 2)
    new = put(base(), "estimators", [{"kind": "centralized"}, {"kind": "local_only"},
                                     {"kind": "ci_consensus", "rounds": 2}])
    assert load_scenario(old) == load_scenario(new)
    assert scenario_hash(load_scenario(old)) == scenario_hash(load_scenario(new))
    # Neither key: the centralized filter alone; an empty list: nothing beside the DKF.
    assert kinds_and_names(load_scenario(base())) == [("centralized", "centralized")]
    assert load_scenario(put(base(), "baselines", [])).estimators == ()
    assert load_scenario(put(base(), "estimators", [])).estimators == ()


def test_both_spellings_are_joined_and_an_explicit_entry_wins():
    """An older file (``baselines:``) with ``--set estimators=[...]``: nothing is
    silently dropped, and an entry given both ways is the explicit one."""
    d = put(put(base(), "baselines", ["centralized", "ci_consensus"]), "consensus_rounds", 2)
    d["estimators"] = [{"kind": "ci_consensus", "rounds": 5}, {"kind": "local_only", "name": "alone"}]
    sc = load_scenario(d)
    assert kinds_and_names(sc) == [("centralized", "centralized"), ("ci_consensus", "ci_consensus"),
                                   ("local_only", "alone")]
    assert sc.estimators[1].rounds == 5
    old = put(base(), "baselines", ["centralized"])
    sc = load_scenario(old, overrides=["estimators=[{kind: no_buffer}]"])
    assert kinds_and_names(sc) == [("centralized", "centralized"), ("no_buffer", "no_buffer")]
    # Two explicit entries of one name are still an error.
    d = put(base(), "estimators", [{"kind": "ci_consensus"}, {"kind": "ci_consensus", "rounds": 2}])
    msg = load_error(d)
    assert "estimators.1" in msg and "'ci_consensus' is taken" in msg, msg


def test_missing_generator_parameter_names_its_params_key():
    d = put(base(), "topology", {"generator": "balanced_tree"})
    msg = load_error(d)
    assert "topology.params.r" in msg and "required by generator balanced_tree" in msg
