"""The ``cellular_sinr`` latency model (issue 23 §2): its shipped fit is the tool's, its draws
are the fit's quantiles, and docs/latency_models.md quotes the KS test the tool computes."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from dkfsim.components.latency import SINR_FIT_FILE, parse_latency
from dkfsim.core.datafiles import DATA_DIR

ROOT = Path(__file__).resolve().parents[1]
T_NS = 10_000_000


def _tool():
    spec = importlib.util.spec_from_file_location("fit_sinr_latency", ROOT / "tools" / "fit_sinr_latency.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def tool_fit():
    tool = _tool()
    return tool, tool.fit()


def test_shipped_fit_is_the_tools_fit(tool_fit):
    tool, result = tool_fit
    assert json.loads(SINR_FIT_FILE.read_text()) == result
    assert SINR_FIT_FILE.read_text() == tool.json_text(result)


def test_docs_quote_the_ks_result(tool_fit):
    tool, result = tool_fit
    docs = (ROOT / "docs" / "latency_models.md").read_text()
    for line in tool.table(result):
        assert line in docs, line
    assert f"fitted on `{'`, `'.join(result['fit_drives'])}`" in docs
    assert f"held-out `{result['test_drive']}`" in docs


def _raw(name):
    """(delay, sinr) of a shipped drive, read here with plain string splitting."""
    lines = (DATA_DIR / "cicv5g" / f"{name}.txt").read_text().splitlines()
    head = lines[0].split()
    d, s = head.index("delay(ms)"), head.index("sinr(db)")
    rows = [line.split() for line in lines[1:] if line.strip()]
    return np.array([float(r[d]) for r in rows]), np.array([float(r[s]) for r in rows])


@pytest.mark.parametrize("sinr, lo, hi", [(3.0, -99, 10), (9.99, -99, 10), (10.0, 10, 15), (14.5, 10, 15),
                                          (15.0, 15, 99), (30.0, 15, 99)])
def test_median_and_max_of_the_sinr_bin(sinr, lo, hi):
    """u = 0.5 draws the median, u = 1 the largest round trip of the fitting drives' rows in
    the SINR's bin (computed here from the raw files); ``one_way`` halves, ``scale`` multiplies."""
    fit = json.loads(SINR_FIT_FILE.read_text())
    pooled = [_raw(n.split("/")[1]) for n in fit["fit_drives"]]
    delay = np.concatenate([p[0] for p in pooled])
    sel = np.concatenate([(p[1] >= lo) & (p[1] < hi) for p in pooled])
    model = parse_latency({"model": "cellular_sinr", "sinr": sinr})
    got = model.from_uniform(np.array([0.5, 1.0]), T_NS)
    assert got.tolist() == [round(np.median(delay[sel]) * 1e6), round(delay[sel].max() * 1e6)]
    assert model.sup_ns(T_NS) == round(delay[sel].max() * 1e6)
    half = parse_latency({"model": "cellular_sinr", "sinr": sinr, "one_way": True, "scale": 3.0})
    assert half.from_uniform(np.array([0.5]), T_NS)[0] == round(np.median(delay[sel]) * 1.5e6)


def test_draws_follow_the_bins_quantiles():
    """A large keyed sample's empirical quantiles match the stored ones (between the levels the
    model interpolates linearly)."""
    fit = json.loads(SINR_FIT_FILE.read_text())
    model = parse_latency({"model": "cellular_sinr", "sinr": 12.0})
    draws = model.sample_ns(np.random.default_rng(5), 200_000, T_NS) / 1e6
    q = np.asarray(fit["bins"][1]["quantiles_ms"])
    for level in (0.1, 0.5, 0.9):
        k = int(level * 200)
        assert abs(np.quantile(draws, level) - q[k]) <= 0.02 * q[k] + 1.0


@pytest.mark.parametrize("spec, words", [
    ({"model": "cellular_sinr"}, "sinr"),
    ({"model": "cellular_sinr", "sinr": "good"}, "sinr"),
    ({"model": "cellular_sinr", "sinr": float("nan")}, "sinr"),
    ({"model": "cellular_sinr", "sinr": 500}, "sinr"),
    ({"model": "cellular_sinr", "sinr": 5, "scale": 0}, "scale"),
    ({"model": "cellular_sinr", "sinr": 5, "snr": 3}, "unknown key"),
])
def test_bad_parameters(spec, words):
    with pytest.raises(ValidationError) as err:
        parse_latency(spec)
    assert words in str(err.value)
