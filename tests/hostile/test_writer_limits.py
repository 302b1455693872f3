"""What the writer accepts the readers read; faults and absurd loads are clean errors (issue 30
§5-§8).

5. one rule for names, applied at validation: a run that is written is read back by every reader;
6. a full disk (a real one: a small tmpfs, where this process may mount it) and a name too long
   end every writing command in one paragraph, exit 2, nothing left behind, earlier output intact;
7. a run whose events would exceed the time limit is refused before it starts, whatever sends
   them; validation is linear in ``links.overrides`` and one link has one override;
8. values that are accepted but meaningless are refused, naming the key; a message names the
   file and shows no number of hundreds of digits.
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import os
import re
import subprocess
import time
from pathlib import Path

import pytest
import yaml
from hostile_kit import CASE1, answers_within, dkfsim_cli

import dkfsim
from dkfsim.cli.main import main
from dkfsim.core.errors import DkfsimError
from dkfsim.experiments.sweep import load_sweep

ROOT = Path(__file__).resolve().parents[2]
CHANNEL = ROOT / "scenarios" / "channel_its_g5.yaml"
CROSSING = ROOT / "scenarios" / "mobility_crossing.yaml"
LONG = "a" * 5000


def cli(*argv) -> tuple[int, str]:
    """``dkfsim ARGV`` in this process: (exit status, what it wrote on stderr)."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        status = main([str(a) for a in argv])
    return status, err.getvalue()


def one_paragraph(status: int, text: str, *words) -> str:
    err = text.strip()
    assert status == 2 and "\n" not in err and err.startswith("dkfsim"), text[-3000:]
    assert len(err) < 2000, len(err)
    for w in words:
        assert w in err, (w, err)
    return err


def base(path=CASE1, steps: int = 20) -> dict:
    return dkfsim.load_scenario(path, overrides=[f"steps={steps}"]).to_dict()


def refused(data: dict, *words) -> str:
    with pytest.raises(DkfsimError) as err:
        dkfsim.load_scenario(data)
    text = str(err.value)
    for w in words:
        assert w in text, (w, text)
    assert not re.search(r"\d{40}", text), text
    return text


# =========================================================================== 5. one rule for names
def test_names_at_the_limit_are_written_and_read_back(tmp_path):
    """A scenario, a sensor and an estimator named with 200 characters: run, saved, plotted,
    reported and loaded."""
    data = base()
    data["name"], data["sensors"][0]["name"] = "n" * 200, "s" * 200
    data["estimators"] = [{"kind": "fusion_centre", "at": 0, "name": "f" * 200}]
    dkfsim.run(dkfsim.load_scenario(data)).save(tmp_path / "run")
    assert dkfsim.load_run(tmp_path / "run").estimates[-1] == "f" * 200
    for argv in (("plot", tmp_path / "run", "--format", "png"), ("report", tmp_path / "run")):
        status, text = cli(*argv)
        assert status == 0, text


@pytest.mark.parametrize("where", ["fusion centre 10000", "estimator 201", "scenario 201", "scenario 10001",
                                   "sensor 201"])
def test_a_name_the_readers_would_refuse_is_refused_when_validated(where):
    """A fusion centre named with 10 000 characters ran and saved; plot, report and load_run then
    refused the folder ("at most 200 characters")."""
    data = base()
    kind, size = where.rsplit(" ", 1)
    name = "x" * int(size)
    if kind == "fusion centre":
        data["estimators"] = [{"kind": "fusion_centre", "at": 0, "name": name}]
        key = "estimators.0.name"
    elif kind == "estimator":
        data["estimators"] = [{"kind": "centralized", "name": name}]
        key = "estimators.0.name"
    elif kind == "scenario":
        data["name"], key = name, "name"
    else:
        data["sensors"][0]["name"], key = name, "sensors.0.name"
    refused(data, key, "at most 200 characters")


def test_a_sweep_setting_the_readers_would_refuse_is_refused_when_loaded(tmp_path):
    """A ``set:`` entry longer than a sweep database's reader takes (10 000 characters)."""
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({
        "scenario": str(CASE1), "runs": 1,
        "set": ["steps=10", "estimators=[{kind: centralized}]" + " " * 10_001]}))
    with pytest.raises(DkfsimError, match=r"set\.1"):
        load_sweep(tmp_path / "s.yaml")


def test_a_long_scenario_file_name_gives_a_name_within_the_limit(tmp_path):
    """A scenario without ``name:`` is named after its file, cut to the limit."""
    path = tmp_path / ("s" * 240 + ".yaml")
    data = base()
    del data["name"]
    path.write_text(json.dumps(data))
    assert dkfsim.load_scenario(path).name == "s" * 200


# =========================================================================== 6. faults
def _mount_problem() -> str:
    if os.geteuid() != 0:
        return "mounting a small tmpfs (a real full disk) needs root; CI runs as root"
    return ""


@pytest.fixture
def small_fs(tmp_path):
    """A tmpfs of 512 kB mounted at ``tmp_path/fs`` (unmounted after): a real file system that
    fills up.  Skipped, saying why, where this process may not mount one."""
    problem = _mount_problem()
    if problem:
        pytest.skip(problem)
    d = tmp_path / "fs"
    d.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=512k", "tmpfs", str(d)], capture_output=True,
                          text=True)
    if done.returncode != 0:
        pytest.skip(f"mount -t tmpfs is refused here ({done.stderr.strip()}); CI mounts one as root")
    try:
        yield d
    finally:
        subprocess.run(["umount", "-l", str(d)], check=False)


def fill(fs: Path) -> None:
    """Fill ``fs`` to the last byte."""
    with contextlib.suppress(OSError), open(fs / "filler", "wb") as fh:
        while True:
            fh.write(b"\0" * 4096)
            fh.flush()


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(".") or p.name.endswith(
        ("-wal", "-shm", "-journal", ".tmp")))


def snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_a_run_on_a_full_disk_is_a_clean_error_and_leaves_nothing(small_fs):
    """It was an OSError traceback from the staging folder's owner file, and the folder stayed."""
    dkfsim_cli("run", CASE1, "--steps", "20", "--out", small_fs / "out", "--quiet").ok()
    before = snapshot(small_fs / "out")
    fill(small_fs)
    dkfsim_cli("run", CASE1, "--steps", "20", "--out", small_fs / "out", "--quiet").clean_error(
        "--out", "No space left on device", "holds what it held before")
    dkfsim_cli("montecarlo", CASE1, "--steps", "20", "--runs", "2", "--jobs", "1", "--out",
               small_fs / "mc", "--quiet").clean_error("No space left on device", "nothing was written")
    assert snapshot(small_fs / "out") == before
    assert leftovers(small_fs) == [] and sorted(p.name for p in small_fs.iterdir()) == ["filler", "out"]


def test_report_and_plot_on_a_full_disk_are_clean_errors_and_leave_nothing(small_fs, tmp_path):
    run = tmp_path / "run"
    dkfsim.run(CASE1, steps=20).save(run)
    fill(small_fs)
    dkfsim_cli("report", run, "--out", small_fs / "r.html").clean_error("r.html", "No space left on device")
    dkfsim_cli("plot", run, "--format", "png", "--out", small_fs / "figs").clean_error("No space left on device")
    assert sorted(p.name for p in small_fs.iterdir()) == ["filler"]


@pytest.mark.parametrize("size", ["64k", "80k", "128k"])
def test_a_sweep_on_a_nearly_full_disk_is_a_clean_error_and_resumes(small_fs, size):
    """A sweep met SQLite's "disk I/O error" (a traceback) and left its -wal and -shm files: at
    each size the sweep ends cleanly, leaves no file beside its database (and no database when
    it saved no task), and once there is room the same command completes it."""
    subprocess.run(["mount", "-o", f"remount,size={size}", str(small_fs)], check=True)
    (small_fs / "s.yaml").write_text(yaml.safe_dump({
        "scenario": str(CASE1), "grid": {"links.default.latency.d_t": list(range(8))},
        "set": ["steps=20", "estimators=[{kind: centralized}]"], "runs": 6}))
    child = dkfsim_cli("sweep", small_fs / "s.yaml", "--jobs", "1", "--quiet")
    if child.returncode != 0:
        child.clean_error("s.sqlite", "full", cpu=120)
    assert leftovers(small_fs) == []
    subprocess.run(["mount", "-o", "remount,size=8m", str(small_fs)], check=True)
    dkfsim_cli("sweep", small_fs / "s.yaml", "--jobs", "1", "--quiet").ok(cpu=120)
    out = dkfsim_cli("sweep", small_fs / "s.yaml", "--dry-run").ok()
    assert out.count("6/6 done") == 8, out
    assert leftovers(small_fs) == []


@pytest.mark.parametrize("command", [
    ("run", CASE1, "--steps", "10", "--out", LONG),
    ("montecarlo", CASE1, "--steps", "10", "--runs", "1", "--out", f"x/{LONG}"),
    ("report", "RUN", "--out", LONG + ".html"),
    ("plot", "RUN", "--format", "png", "--out", LONG),
    ("sweep", "SWEEP", "--db", LONG + ".sqlite", "--jobs", "1"),
    ("sweep", "DB", "--export", LONG + ".csv"),
], ids=["run", "montecarlo", "report", "plot", "sweep --db", "sweep --export"])
def test_a_name_too_long_is_a_clean_error(tmp_path, monkeypatch, command):
    """A 5000-character --out ended in a "File name too long" traceback."""
    monkeypatch.chdir(tmp_path)
    run = tmp_path / "run"
    dkfsim.run(CASE1, steps=10).save(run)
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({"scenario": str(CASE1), "runs": 1,
                                                     "set": ["steps=10", "estimators=[]"]}))
    if "DB" in command:
        assert main(["sweep", str(tmp_path / "s.yaml"), "--jobs", "1", "--quiet"]) == 0
    argv = [{"RUN": run, "SWEEP": tmp_path / "s.yaml", "DB": tmp_path / "s.sqlite"}.get(str(a), a) for a in command]
    before = sorted(p.name for p in tmp_path.iterdir())
    one_paragraph(*cli(*argv), "too long")
    assert sorted(p.name for p in tmp_path.iterdir()) == before


# =========================================================================== 7. loads
BACKGROUND = {"arrivals": "poisson", "packets_per_second": 1.0e9, "size": 100}


def _loaded(source: str) -> dict:
    if source == "link background":
        data = base(steps=1000)
        data["links"]["default"].update(rate=1.0e6, background=BACKGROUND)
    elif source == "an override's background":
        data = base(steps=1000)
        data["links"]["overrides"] = [{"link": [0, 1], "rate": 1.0e6, "background": BACKGROUND}]
    elif source == "channel background":
        data = base(CHANNEL, steps=1000)
        data["medium"]["background"] = BACKGROUND
    elif source == "moving vehicles with link background":
        data = base(CROSSING, steps=300)
        data["links"]["default"].update(rate=1.0e6, background=BACKGROUND)
    else:                                   # estimator traffic
        data = base(steps=1000)
        data["estimators"] = [{"kind": "ci_consensus", "rounds": 10**7}]
    return data


@pytest.mark.parametrize("source", ["link background", "an override's background", "channel background",
                                    "moving vehicles with link background", "estimator traffic"])
def test_a_run_of_absurd_load_is_refused_before_it_starts(tmp_path, source):
    """``links.default.background`` at 1e9 packets/s: validate estimated 0.086 s and run hung (the
    same rate under ``medium.background`` was refused up front).  Every source of events counts
    in the estimate; the refusal names the scenario's file."""
    path = tmp_path / "loaded.yaml"
    path.write_text(json.dumps(_loaded(source)))
    child = dkfsim_cli("run", path, "--out", tmp_path / "out", timeout=90)
    child.clean_error(str(path), "would take", "--yes", cpu=30)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("pair", ["the same link twice", "an undirected link and its reverse",
                                  "a directed arc twice"])
def test_one_link_takes_one_override(pair):
    data = base()
    first = data["topology"]["edges"][0]
    second = {"the same link twice": first, "an undirected link and its reverse": first[::-1],
              "a directed arc twice": first}[pair]
    if pair == "a directed arc twice":
        data["topology"]["directed"], data["protocol"] = True, "flood"
    data["links"]["overrides"] = [{"link": first, "loss": 0.1}, {"link": second, "latency": {"model": "constant"}}]
    refused(data, "links.overrides.1.link", "already has an override")


def test_a_directed_arc_and_its_reverse_are_two_links():
    data = base()
    data["topology"]["directed"], data["protocol"] = True, "flood"
    data["topology"]["edges"] = data["topology"]["edges"] + [e[::-1] for e in data["topology"]["edges"]]
    first = data["topology"]["edges"][0]
    data["links"]["overrides"] = [{"link": first, "loss": 0.1}, {"link": first[::-1], "loss": 0.2}]
    sc = dkfsim.load_scenario(data)
    assert sc.link_spec(*first).loss == 0.1 and sc.link_spec(*first[::-1]).loss == 0.2


def test_eight_thousand_overrides_validate_in_seconds(tmp_path):
    """A complete graph of 128 nodes with one override per edge (8128): validation took over
    120 s (every link scanned every override); its CPU time is bounded here."""
    data = base(steps=4)
    n = 128
    data["sensors"] = [dict(data["sensors"][0], name=f"s{i}") for i in range(n)]
    edges = [[u, v] for u in range(n) for v in range(u + 1, n)]
    data["topology"] = {"directed": False, "generator": "edges", "edges": edges}
    data["spanning_tree"] = True
    data["links"] = {"default": {"latency": {"model": "constant"}},
                     "overrides": [{"link": e, "loss": 0.01 * (i % 7)} for i, e in enumerate(edges)]}
    data["estimators"] = []
    (tmp_path / "big.yaml").write_text(json.dumps(data))
    start = time.process_time()
    with answers_within(120):
        sc = dkfsim.load_scenario(tmp_path / "big.yaml")
    assert time.process_time() - start < 20
    assert sc.link_spec(5, 3).loss == 0.01 * (edges.index([3, 5]) % 7)


# =========================================================================== 8. meaningless values
@pytest.mark.parametrize("queue", [{"bytes": 1}, {"bytes": 299}, {"packets": 0}])
def test_a_channel_queue_that_holds_no_frame_is_refused(queue):
    """``medium.queue: {bytes: 1}`` dropped every frame while ``{packets: 0}`` was refused."""
    data = base(CHANNEL)
    data["medium"]["queue"] = queue
    refused(data, f"medium.queue.{next(iter(queue))}", "at least one frame" if "packets" in queue else "300")


def test_a_channel_queue_that_holds_its_frames_is_accepted():
    data = base(CHANNEL)
    data["medium"]["queue"] = {"bytes": 300}
    assert dkfsim.load_scenario(data).medium.queue.bytes == 300


@pytest.mark.parametrize("rate", [1e-300, 0.5, 1e100, 1e19])
def test_a_rate_from_distance_is_held_to_link_rates(rate):
    """``mobility.links.rate`` took 1e-300 and 1e100; link rates are 1 .. 1e18 bit/s."""
    data = base(CROSSING)
    data["mobility"]["links"] = {"rate": [[0.0, 1.0e6], [50.0, rate]]}
    refused(data, "mobility.links.rate.1.1")


@pytest.mark.parametrize("keys", [(0, "0"), ("0", 0), (1, "01"), ("05", 5)])
def test_a_vehicle_given_twice_is_refused(keys):
    """Vehicles given as both ``0:`` and ``'0':``: one was dropped silently (every node still had
    a trajectory, so nothing else complained)."""
    data = base(CROSSING)
    vehicles = data["mobility"]["vehicles"]
    node = str(int(keys[1]))
    first, second = copy.deepcopy(vehicles[node]), copy.deepcopy(vehicles[node])
    second["start"] = [first["start"][0] + 1.0, first["start"][1]]
    del vehicles[node]
    vehicles[keys[0]], vehicles[keys[1]] = first, second
    refused(data, "mobility.vehicles", "given twice")


@pytest.mark.parametrize("edit", [
    lambda d: d.update(steps=10**300),
    lambda d: d.update(buffer_length=10**300),
    lambda d: d["links"].update(d_t=10**300),
    lambda d: d.update(estimators=[{"kind": "ci_consensus", "rounds": 10**300}]),
    lambda d: d.update(estimators=[{"kind": "fusion_centre", "at": 10**300}]),
    lambda d: d["topology"].update(edges=[[0, 10**300]]),
    lambda d: d["model"].update(T=10**300),
], ids=["steps", "buffer_length", "links.d_t", "rounds", "centre at", "edges", "T"])
def test_a_message_shows_no_number_of_hundreds_of_digits(edit):
    """A 300-digit value was printed in full (in a value or a key); it is written in short now."""
    data = base()
    edit(data)
    text = refused(data)
    assert "e+300" in text, text


def test_a_refusal_of_work_names_the_scenario_file(tmp_path):
    """Resource refusals named the scenario's ``name:``; they name its file now."""
    data = base(steps=10**6)
    data["name"] = "something_else"
    data["estimators"] = [{"kind": "ci_consensus", "rounds": 10**5}]
    (tmp_path / "mine.yaml").write_text(json.dumps(data))
    with pytest.raises(DkfsimError) as err:
        dkfsim.run(dkfsim.load_scenario(tmp_path / "mine.yaml"))
    assert str(err.value).startswith(str(tmp_path / "mine.yaml")), str(err.value)
