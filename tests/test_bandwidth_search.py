"""The bandwidth twin of ``maxdelay`` (``dkfsim maxdelay --axis rate``, docs/traffic.md): the
least link rate within a tolerance, against the metric computed run by run at every candidate
rate; the lower bound from the packet sizes against a run without any rate key and against the
utilisation it predicts; clear errors for bad arguments."""

from __future__ import annotations

import json
import re

import pytest
import yaml
from test_maxdelay import const_latency, dkfsim_cli, rw_scenario

import dkfsim
from dkfsim.components.traffic import transmission_ns
from dkfsim.core.errors import DkfsimError
from dkfsim.experiments.maxdelay import MaxDelay, Settings
from dkfsim.experiments.maxdelay.rate import NO_LIMIT, make_rate_axis


def rated(rate=1e6, **kw):
    data = rw_scenario(const_latency(0.5), **kw)
    data["links"]["default"]["rate"] = rate
    return data


def test_axis_values_and_overrides():
    """Candidate 0 is no limit, j >= 1 ``max_rate / step^(j-1)``; every-link mode keeps an
    override's ratio to the default rate; one-link mode appends an entry (the last one wins)."""
    data = rated(2e6)
    data["links"]["overrides"] = [{"link": [1, 2], "rate": 5e5}]
    sc = dkfsim.load_scenario(data)
    ax = make_rate_axis(sc, max_rate=1e6, min_rate=1e3, step=10.0)
    assert ax.max_index == 4 and [ax.value(j) for j in range(5)] == [NO_LIMIT, 1e6, 1e5, 1e4, 1e3]
    assert ax.overrides(2) == ["links.default.rate=100000.0", "links.overrides.0.rate=25000.0"]
    s2 = ax.scenario(2)
    assert s2.link_spec(0, 1).rate == 1e5 and s2.link_spec(2, 1).rate == 2.5e4
    one = make_rate_axis(sc, max_rate=1e6, min_rate=1e3, step=10.0, link="2,3")
    s3 = one.scenario(3)
    assert s3.link_spec(2, 3).rate == 1e4 and s3.link_spec(3, 2).rate == 1e4
    assert s3.link_spec(0, 1).rate == 2e6 and s3.link_spec(1, 2).rate == 5e5


def test_least_rate_is_where_the_packets_stop_taking_0_ns():
    """Zero latency and a buffer of one row: a contribution counts only if it arrives at its
    tick, i.e. only if its packet's transmission rounds to 0 ns (``size * 8e9 / rate < 0.5``).
    trace(P_fused) is deterministic here (one run per candidate), equal to the unlimited value
    at every rate where that holds and larger below.  So the least rate within a 1 %
    tolerance is the least candidate at which the DKF's packets (their size from a run without
    a rate) take 0 ns."""
    data = rw_scenario(const_latency(0.0), steps=40)
    plain = dkfsim.run(dkfsim.load_scenario(data)).counts
    size = plain["bytes"] // plain["sent"]
    assert plain["bytes"] == size * plain["sent"]          # (every packet of one size here)
    data["links"]["default"]["rate"] = 1e6
    sc = dkfsim.load_scenario(data)
    ax = make_rate_axis(sc, max_rate=1e13, min_rate=1e10, step=2.0)
    expected = min(ax.value(j) for j in range(1, ax.max_index + 1) if transmission_ns(size, ax.value(j)) == 0)
    assert 1e10 < expected < 1e13
    res = MaxDelay(sc, Settings(metric="trace_P", relative=1.01, axis="rate", max_rate=1e13,
                                min_rate=1e10, rate_step=2.0)).run()
    assert res.emp.status == "decided" and res.answer == expected
    cands = res.md.cands
    assert all(c.runs == 1 for c in cands.values())
    at = next(c for c in cands.values() if c.delay == expected)
    assert at.mean == cands[0].mean
    d = res.to_dict()
    assert d["axis"]["mode"] == "rate" and d["worst_case"] is None
    assert d["empirical"]["first_exceeding"] == ax.value(at.index + 1)
    assert d["rate_lower_bound"]["rate"] > 0 and "lower bound" in res.table()


def test_lower_bound_is_the_busiest_links_bytes_plus_background():
    """The bound is the payload (bytes less a 16-byte header per packet, x 8 / (K T)) on the
    busiest link of a run with no rate key at all, plus the background's bits per second; at
    0.8 x the bound that link's transmitter ends up busy all the time and contributions come
    late (the contents do not fit, however the rate-limited exchange packs them)."""
    data = rated(steps=80)
    data["links"]["default"]["background"] = {"arrivals": "periodic", "packets_per_second": 2.0, "size": 40}
    sc = dkfsim.load_scenario(data)
    bound = MaxDelay(sc, Settings(metric="trace_P", tolerance=1.0, axis="rate", max_rate=1e4,
                                  min_rate=1e3, rate_step=10.0)).run().rate_bound
    plain = rw_scenario(const_latency(0.5), steps=80)
    rows = dkfsim.run(dkfsim.load_scenario(plain)).counts["per_link"]
    busiest = max(rows, key=lambda r: r["bytes"])
    assert bound["own_bit_per_s"] == pytest.approx(busiest["bytes"] * 8 / 80.0, rel=1e-12)
    payload = (busiest["bytes"] - 16 * busiest["sent"]) * 8 / 80.0
    assert bound["background_bit_per_s"] == 2.0 * 40 * 8
    assert bound["rate"] == pytest.approx(payload + 640.0, rel=1e-12)
    assert bound["demand_rate"] == pytest.approx(bound["own_bit_per_s"] + 640.0, rel=1e-12)
    slow = dkfsim.load_scenario(data, overrides=[f"links.default.rate={0.8 * bound['rate']!r}"])
    r = dkfsim.run(slow)
    e = [tuple(link) for link in r.arrays["rated_links"]].index(tuple(bound["link"]))
    assert r.arrays["utilisation"][-10:, e].min() > 0.999        # saturated by the end of the run
    assert r.counts["late"] > 0                                 # and contributions miss their rows


@pytest.mark.parametrize("args, expected", [
    (["--link", "0,1"], "--link: names the link whose rate --axis rate searches"),
    (["--axis", "rate", "--link", "0,3"], "--link 0,3: not a link"),
    (["--axis", "rate", "--link", "zero"], "--link: expected two node numbers"),
    (["--axis", "rate", "--rate-step", "1"], "--rate-step: must be a factor > 1"),
    (["--axis", "rate", "--min-rate", "1e6", "--max-rate", "1e5"], "--min-rate (1e+06) must not exceed"),
    (["--axis", "rate", "--max-rate", "0"], "--max-rate: must be a rate"),
])
def test_bad_arguments_are_one_paragraph(tmp_path, args, expected):
    f = tmp_path / "s.yaml"
    f.write_text(yaml.safe_dump(rated(steps=20)))
    p = dkfsim_cli("maxdelay", f, "--out", tmp_path / "o", "--tolerance", "1", *args)
    assert p.returncode == 2, p.stderr
    assert expected in p.stderr and p.stderr.startswith("dkfsim maxdelay: error:"), p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and not (tmp_path / "o").exists()


def test_cli_prints_and_stores_the_answer_beside_the_bound(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text(yaml.safe_dump(rated(steps=30)))
    out = tmp_path / "o"
    p = dkfsim_cli("maxdelay", f, "--out", out, "--axis", "rate", "--metric", "trace_P", "--relative", "1.05",
                   "--max-rate", "1e4", "--min-rate", "100", "--rate-step", "4")
    assert p.returncode == 0, p.stderr
    assert "(1) empirical:   rate" in p.stdout and "(2) lower bound: rate >=" in p.stdout
    # the reference is the unlimited rate (it read "zero delay"), and no worst case ran on this axis
    assert "paired with the same runs at unlimited rate" in p.stdout and "zero delay" not in p.stdout + p.stderr
    assert "paired excess over R x the same run at unlimited rate" in p.stderr
    assert re.search(r"^  \d+ runs in [\d.]+ s$", p.stdout, re.M), p.stdout
    d = json.loads((out / "maxdelay.json").read_text())
    assert d["rate_lower_bound"]["link"] and d["empirical"]["candidates"][0]["delay"] == NO_LIMIT
    assert (out / "maxdelay.png").stat().st_size > 0
    with pytest.raises(DkfsimError, match="--axis: unknown axis"):
        MaxDelay(dkfsim.load_scenario(rated()), Settings(tolerance=1.0, axis="bandwidth"))
