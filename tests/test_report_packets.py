"""Every report's packets table adds up (issue 34 §5): each row shows every term of
``sent + copies = delivered + lost + queue_dropped + crash_dropped + in_flight``, with ``lost``
split by cause where the run has one (outage, out of range, collision), read back from the
rendered HTML; and the channel report lists the channel's parameters with their units.

Before, a channel run's table left out the packets full radio queues dropped (2,648 of 12,495
DKF packets in the issue's run), so its rows did not add up."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_report import Page

import dkfsim
from dkfsim.report.html_report import write_report

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "scenarios"

#: Runs whose packets meet the causes: a channel with one-frame radio queues (queue drops and
#: collisions), links that come and go, outages, duplicated packets and crashes.
RUNS = {
    "channel": (SCENARIOS / "channel_its_g5.yaml", ["steps=120", "medium.queue={packets: 1}"]),
    "mobility": (SCENARIOS / "mobility_convoy.yaml", ["steps=120"]),
    "outage": (SCENARIOS / "stress_outage.yaml", ["steps=200"]),
    "copies and crashes": (SCENARIOS / "paper_case1.yaml", [
        "steps=120", "links.default.duplicate=0.2", "faults={crashes: [{node: 3, start: 0.3, end: 0.6}]}",
        "estimators=[{kind: centralized}, {kind: ci_consensus, rounds: 2}]"]),
}


def packets_table(report: Path) -> list[dict[str, float | None]]:
    """The rendered packets table: one dict per row, the head's words to the numbers."""
    rows = Page(report.read_text()).tables["packets"]
    head = rows[0]
    out = []
    for row in rows[1:]:
        out.append({h.split(" [")[0]: (None if c == "–" else float(c)) if i else c
                    for i, (h, c) in enumerate(zip(head, row))})
    return out


def adds_up(row: dict, rel: float = 0.0) -> None:
    """``sent + copies = delivered + lost + dropped + in flight``, and ``lost`` its causes' sum."""
    if row["sent"] is None:                          # not modelled (the centralized filter)
        return
    left = row["sent"] + row["duplicate copies"]
    right = row["delivered"] + row["lost"] + row["dropped: full queue"] + row["dropped: crashed node"] \
        + row["in flight at end"]
    assert right == pytest.approx(left, rel=rel, abs=0), row
    parts = [v for k, v in row.items() if k.startswith("lost: ")]
    if parts:
        assert sum(parts) == pytest.approx(row["lost"], rel=rel, abs=0), row


def test_the_identity_check_sees_a_missing_term():
    row = {"sent": 10.0, "duplicate copies": 2.0, "delivered": 6.0, "lost": 2.0, "lost: link loss": 1.0,
           "lost: collision": 1.0, "dropped: full queue": 3.0, "dropped: crashed node": 0.0,
           "in flight at end": 1.0}
    adds_up(row)
    with pytest.raises(AssertionError):
        adds_up({**row, "dropped: full queue": 0.0})
    with pytest.raises(AssertionError):
        adds_up({**row, "lost: collision": 0.0})


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    out = {}
    for name, (path, overrides) in RUNS.items():
        folder = tmp_path_factory.mktemp(name.replace(" ", "_"))
        dkfsim.run(path, overrides=overrides, save="estimates").save(folder / "run")
        out[name] = write_report(folder / "run")
    return out


@pytest.mark.slow                         # (its fixture: four runs and their reports, 14 s)
@pytest.mark.parametrize("name", RUNS)
def test_a_run_reports_packet_table_adds_up(reports, name):
    rows = packets_table(reports[name])
    assert rows and all(set(r) >= {"sent", "duplicate copies", "delivered", "lost", "dropped: full queue",
                                   "dropped: crashed node", "in flight at end"} for r in rows)
    for row in rows:
        adds_up(row)
    dkf = rows[0]
    cause = {"channel": "lost: collision", "outage": "lost: outage"}
    if name in cause:
        assert dkf[cause[name]] > 0, dkf                   # the run has that cause, and shows it
    if name == "channel":
        assert dkf["dropped: full queue"] > 0, dkf        # what the table used to leave out
    if name == "copies and crashes":
        assert dkf["duplicate copies"] > 0 and dkf["dropped: crashed node"] > 0, dkf


@pytest.mark.slow
def test_the_channel_report_lists_the_channel_with_units(reports):
    table = dict(row for row in Page(reports["channel"].read_text()).tables["channel_parameters"][1:])
    assert float(table["rate [bit/s]"]) == 6e6
    assert float(table["slot [µs]"]) == pytest.approx(13.0) and float(table["AIFS [µs]"]) > 0
    assert float(table["radio queue [packets]"]) == 1
    assert table["access"] == "csma" and float(table["background per node [frames/s]"]) > 0


@pytest.mark.slow
def test_a_montecarlo_reports_packet_table_adds_up(tmp_path):
    path, overrides = RUNS["channel"]
    mc = dkfsim.montecarlo(path, runs=2, jobs=1, overrides=overrides)
    mc.save(tmp_path / "mc")
    rows = packets_table(write_report(tmp_path / "mc"))
    assert len(rows) == len(mc.estimates)
    for row in rows:
        adds_up(row, rel=1e-5)                            # (means over runs, printed to 6 digits)
    assert rows[0]["dropped: full queue"] > 0 and rows[0]["lost: collision"] > 0, rows[0]
