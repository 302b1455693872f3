"""The spatial radio as a user meets it (issue 32): a scenario with ``medium.radio``, ``access:
{kind: edca}``, ``generation_jitter`` and bystanders run from the command line; what summary.json,
run.npz, ``dkfsim plot`` and ``dkfsim report`` show of it, read against each other; bad keys and
tampered result files as one clear message, exit 2."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from dkfsim.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
CHANNEL = ROOT / "scenarios" / "channel_its_g5.yaml"
BYSTANDERS = 20


def radio_scenario(tmp: Path, **medium) -> Path:
    """channel_its_g5's twelve vehicles on a two-lane road at 25 m/s, on a spatial radio under
    EDCA with a 5 ms generation jitter and random beacon phases, and 20 bystanders driving the
    other way."""
    s = yaml.safe_load(CHANNEL.read_text())
    s["mobility"] = {"vehicles": {"default": {"kind": "road", "spacing": 40.0, "lanes": 2, "speed": 25.0}},
                     "range": {"model": "disk", "radius": 5000.0}}
    s["medium"].update({"access": {"kind": "edca"}, "generation_jitter": 0.005,
                        "radio": {"path_loss": {"model": "winner_b1"}, "shadowing": {"model": "lognormal", "sigma": 3.0},
                                  "fading": {"model": "nakagami", "m": 1.5}},
                        "bystanders": {"count": BYSTANDERS, "vehicles": {"default": {
                            "kind": "road", "spacing": 30.0, "speed": -25.0, "start": [0.0, 12.0]}}}})
    s["medium"]["background"]["offset"] = "random"
    s["medium"].update(medium)
    s["estimators"] = [{"kind": "centralized"}, {"kind": "ci_consensus"}]
    path = tmp / "radio.yaml"
    path.write_text(yaml.safe_dump(s))
    return path


def cli(*args: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(list(args))
        except SystemExit as exc:
            code = int(exc.code or 0)
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    d = tmp_path_factory.mktemp("radio")
    code, _, err = cli("run", str(radio_scenario(d)), "--steps", "60", "--quiet", "--out", str(d / "run"))
    assert code == 0, err
    return d / "run"


def test_the_run_reports_pdr_cbr_and_the_four_causes_consistently(run):
    s = json.loads((run / "summary.json").read_text())
    ch = s["packets"]["channel"]
    assert s["traffic"]["fused"]["channel"] == ch                  # the scenario's DKF's copy
    members = 12 + BYSTANDERS
    assert len(ch["cbr"]) == members and ch["cbr_mean"] == pytest.approx(np.mean(ch["cbr"]))
    # every frame on the air reaches every other member once: received or lost by one cause
    assert ch["pairs"] == ch["frames_on_air"] * (members - 1)
    assert ch["pairs"] == ch["pairs_received"] + sum(ch["losses"].values())
    pdr = ch["pdr_by_distance"]
    assert len(pdr["bins_m"]) == len(pdr["pdr"]) + 1 == len(pdr["frames"]) + 1
    for i, frames in enumerate(pdr["frames"]):
        lost = sum(pdr[c][i] for c in ("sensing", "receiver_busy", "propagation", "collision"))
        if frames:
            assert pdr["pdr"][i] == pytest.approx((frames - lost) / frames)
        else:
            assert pdr["pdr"][i] is None
    z = np.load(run / "run.npz")
    assert z["cbr"].shape == (60, members) and z["cbr_nodes"].tolist() == list(range(members))
    assert z["cbr"].mean(axis=0) == pytest.approx(np.array(ch["cbr"]), rel=1e-12)
    # the bystanders send only background: the consensus filter's copy carries other frames
    # of the nodes, the same background
    assert s["traffic"]["ci_consensus"]["channel"]["background_sent"] > 0


def test_the_radio_figure_is_drawn_and_the_report_lists_the_radio(run, tmp_path):
    """``dkfsim plot``'s radio figure (the report draws the folder's figures inline with the same
    function), and the report's radio table and parameters."""
    pytest.importorskip("matplotlib")
    from dkfsim.report.plots import load_folder, plot_radio
    written = plot_radio(load_folder(run), tmp_path / "radio", ("png",))
    assert [p.name for p in written] == ["radio.png"] and written[0].stat().st_size > 10_000
    tables = tmp_path / "tables"                 # (the tables alone: the report's figures are plot's)
    tables.mkdir()
    for name in ("summary.json", "rows.csv"):
        shutil.copy(run / name, tables / name)
    code, _, err = cli("report", str(tables), "--out", str(tmp_path / "r.html"))
    assert code == 0, err
    page = (tmp_path / "r.html").read_text()
    assert 'id="radio"' in page and "lost: collision" in page and "carrier sense threshold" in page


@pytest.mark.parametrize("where, value, words", [
    (("pdr_by_distance", "pdr"), [0.5], "distance bins"),
    (("pdr_by_distance", "frames", 0), -1, "greater than or equal to 0"),
    (("cbr", 0), 1.5, "less than or equal to 1"),
    (("losses", "collision"), "many", "integer"),
])
def test_a_tampered_radio_block_is_one_message_naming_the_key(run, tmp_path, where, value, words):
    bad = tmp_path / "bad"
    shutil.copytree(run, bad)
    s = json.loads((bad / "summary.json").read_text())
    node = s["packets"]["channel"]
    for key in where[:-1]:
        node = node[key]
    node[where[-1]] = value
    (bad / "summary.json").write_text(json.dumps(s))
    code, out, err = cli("report", str(bad), "--out", str(tmp_path / "r.html"))
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "packets.channel." + ".".join(str(w) for w in where[:2]) in err and words in err


@pytest.mark.parametrize("edit, key, words", [
    ({"radio": None}, "medium.bystanders", "need a spatial radio"),
    ({"radio": {"path_loss": {"model": "winner"}}}, "medium.radio.path_loss", "winner_b1"),
    ({"generation_jitter": 0.5}, "medium.generation_jitter", "at most the tick"),
    ({"access": {"kind": "edca", "eifs": -1}}, "medium.access.eifs", "must be >= 0"),
    ({"bystanders": {"count": 3, "vehicles": {"5": {"kind": "road", "spacing": 10.0}}}},
     "medium.bystanders.vehicles.5", "out of range"),
    ({"bystanders": {"sumo_fcd": {"file": "missing.fcd.xml"}}}, "medium.bystanders.sumo_fcd.file:",
     "file not found"),
])
def test_bad_radio_keys_are_one_message_naming_the_key(tmp_path, edit, key, words):
    path = radio_scenario(tmp_path, **edit)
    code, out, err = cli("validate", str(path))
    assert code == 2 and "Traceback" not in err, err
    assert key in err and words in err and str(path.name) in err


def test_a_radio_without_positions_names_mobility(tmp_path):
    s = yaml.safe_load(CHANNEL.read_text())
    s["medium"]["radio"] = {}
    path = tmp_path / "r.yaml"
    path.write_text(yaml.safe_dump(s))
    code, out, err = cli("validate", str(path))
    assert code == 2 and "medium.radio" in err and "mobility" in err


def test_edca_switches_a_shipped_scenario_from_the_command_line(tmp_path):
    """``--set medium.access.kind=edca`` on the one-domain channel: its twelve synchronized senders
    all go at once when the medium has been idle (no backoff), so far more frames collide than
    under csma."""
    res = {}
    for kind in ("csma", "edca"):
        code, _, err = cli("run", str(CHANNEL), "--steps", "30", "--save", "summary", "--quiet",
                           "--set", f"medium.access.kind={kind}", "--out", str(tmp_path / kind))
        assert code == 0, err
        res[kind] = json.loads((tmp_path / kind / "summary.json").read_text())["packets"]["channel"]
    share = {k: c["frames_collided"] / c["frames"] for k, c in res.items()}
    assert share["edca"] > share["csma"] + 0.2


def test_an_override_by_number_changes_the_vehicle_the_file_writes_as_an_integer_key(tmp_path):
    """YAML reads ``0:`` as the integer 0: ``--set mobility.vehicles.0.speed=...`` changes that
    vehicle (it added a key '0' beside it, refused as vehicle 0 given twice), and so for a
    bystander."""
    from dkfsim.config.load import load_scenario
    path = radio_scenario(tmp_path)
    s = yaml.safe_load(path.read_text())
    road = {"kind": "road", "spacing": 40.0, "lanes": 2, "speed": 25.0}
    s["mobility"]["vehicles"][0] = dict(road)
    s["medium"]["bystanders"]["vehicles"][1] = dict(road, speed=-25.0)
    path.write_text(yaml.safe_dump(s))
    assert "\n    0:" in path.read_text()          # (an integer key in the file)
    sc = load_scenario(str(path), ["mobility.vehicles.0.speed=30", "medium.bystanders.vehicles.1.speed=-31"])
    def vx(traj):
        return traj.velocity[0]
    assert vx(sc.mobility.trajectory(0)) == 30.0 and vx(sc.mobility.trajectory(1)) == 25.0
    assert vx(sc.medium.bystanders.trajectory(1)) == -31.0 and vx(sc.medium.bystanders.trajectory(0)) == -25.0
    code, out, err = cli("validate", str(path), "--set", "mobility.vehicles.0.speed=30")
    assert code == 0, err
