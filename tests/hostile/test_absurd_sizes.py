"""Sizes the schema accepts that a run's arrays follow: either the arrays follow what the run
does, or the memory estimate counts them and ``validate`` and ``run`` refuse the run in one
paragraph before it starts.

* ``links.default.queue.packets`` up to 2**40: a FIFO transmitter's ring of waiting packets
  grows with the packets that wait (it was allocated at the waiting room's size: 32 TiB);
* ``medium.bystanders`` over many ticks: a spatial radio keeps every vehicle's position at every
  tick (and copies of them), counted in the estimate (``steps=100000`` and 10 000 bystanders
  asked for 15 GiB and more and ended in a traceback, validate having said "93.1 MiB").
"""

from __future__ import annotations

import resource

import pytest
from hostile_kit import CASE1, dkfsim_cli

import dkfsim
import dkfsim.core.resources as resources
from dkfsim.config.plan import RunPlan
from dkfsim.core.errors import ResourceError
from dkfsim.engine.estimate import RADIO_COPY_BYTES, RADIO_PLACES_BYTES, RADIO_SERIES_BYTES, estimate_run

#: Four sensors on a spatial radio with a road mobility and ten bystanders on the other lane.
RADIO = """
name: small_radio
seed: 1
steps: 20
model:
  kind: constant_acceleration
  T: 0.01
  Q: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
prior:
  mean: [0, 0, 0]
  cov: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
sensors:
  - {name: s1, H: [[1, 0, 0]], R: [[0.8]]}
  - {name: s2, H: [[0, 1, 0]], R: [[1.0]]}
  - {name: s3, H: [[0, 0, 1]], R: [[2.0]]}
  - {name: s4, H: [[1, 0, 0]], R: [[1.0]]}
topology:
  generator: edges
  edges: [[0, 1], [0, 2], [0, 3]]
links:
  default:
    latency: {model: constant, value: 5.0e-6}
  d_t: 2
mobility:
  vehicles: {default: {kind: road, spacing: 40.0, lanes: 2, speed: 25.0}}
  range: {model: disk, radius: 5000.0}
medium:
  rate: 6.0e+6
  preamble: 40.0e-6
  access: {kind: edca}
  generation_jitter: 0.005
  queue: {packets: 2}
  background: {arrivals: periodic, packets_per_second: 10, size: 300, offset: random}
  radio:
    path_loss: {model: winner_b1}
    shadowing: {model: lognormal, sigma: 3.0}
    fading: {model: nakagami, m: 1.5}
  bystanders:
    count: 10
    vehicles: {default: {kind: road, spacing: 30.0, speed: -25.0, start: [0.0, 12.0]}}
protocol: tree
estimators:
  - {kind: centralized}
"""

MANY = ["--set", "steps=100000", "--set", "medium.bystanders.count=10000", "--set", "medium.background=null"]


def at_most(gib: int):
    """A child whose address space is ``gib`` GiB: what it can give a run, whatever the machine."""
    def apply():
        resource.setrlimit(resource.RLIMIT_AS, (gib << 30, resource.getrlimit(resource.RLIMIT_AS)[1]))
    return apply


@pytest.fixture
def radio(tmp_path):
    path = tmp_path / "radio.yaml"
    path.write_text(RADIO)
    return path


def test_many_runs_that_cannot_fit_say_what_shrinks_them(radio, tmp_path):
    """A Monte Carlo, a sweep or maxdelay whose runs cannot fit is refused with what shrinks its
    memory -- fewer workers, each holding one run, or a smaller run -- not with what shortens its
    time: "fewer --runs" and "more --jobs" would leave it as large or make it larger."""
    sweep = tmp_path / "s.yaml"
    sweep.write_text(f"scenario: {radio}\nruns: 2\nset: {MANY[1::2]!r}\noutput: {tmp_path / 's.sqlite'}\n")
    for command in (("montecarlo", radio, "--runs", 4, "--out", tmp_path / "mc", *MANY),
                    ("maxdelay", radio, "--relative", 1.5, "--out", tmp_path / "md", *MANY),
                    ("sweep", sweep)):
        err = dkfsim_cli(*command, "--jobs", 2, preexec=at_most(16)).clean_error(
            "needs about 138 GiB of memory", "fewer workers (each of the 2 holds one run)",
            "medium.bystanders")
        assert "more --jobs" not in err, err
    # what the search keeps of each candidate shrinks with its axis; a Monte Carlo's rows with its runs
    dkfsim_cli("maxdelay", radio, "--relative", 1.5, "--scale-step", 1e-9, "--out", tmp_path / "md2",
               preexec=at_most(16)).clean_error("candidates", "a larger --scale-step, a smaller --max-scale")
    err = dkfsim_cli("montecarlo", radio, "--runs", 10**8, "--jobs", 1, "--out", tmp_path / "mc2",
                     preexec=at_most(16)).clean_error("results kept", "fewer --runs (their rows are kept)")
    assert "fewer workers" not in err, err                    # (one worker: nothing to take away)
    with pytest.raises(ResourceError, match=r"fewer runs \(their rows are kept\), fewer workers") as info:
        dkfsim.montecarlo(radio, runs=4, jobs=2, overrides=MANY[1::2])
    assert "--" not in str(info.value).split("give it")[1]


def test_bystanders_over_many_ticks_are_refused_by_validate_and_run(radio, tmp_path):
    """10 000 bystanders over 100 000 ticks: their positions alone are about 69 GiB (17 bytes a
    vehicle and tick in the plan, 41 in the channel, 16 in its busy ratio series), refused by
    validate as by run, with the memory in GiB and the key, before anything is computed."""
    err = dkfsim_cli("validate", radio, *MANY, preexec=at_most(16)).clean_error(
        "radio.yaml", "needs about 69 GiB of memory", "positions of 10004 vehicles on the radio",
        "medium.bystanders", "more than the")
    assert "dkfsim validate" in err
    out = tmp_path / "out"
    dkfsim_cli("run", radio, "--out", out, *MANY, preexec=at_most(16)).clean_error(
        "radio.yaml", "needs about 69 GiB of memory", "medium.bystanders", "--steps")
    assert not out.exists()
    assert "69 GiB" not in dkfsim_cli("validate", radio, preexec=at_most(16)).ok()


def test_the_estimate_counts_every_vehicle_at_every_tick(radio):
    """The radio's item is ticks x vehicles (plus one copy of the channel per estimator with a
    network); a scenario without bystanders counts its nodes."""
    def radio_bytes(overrides):
        est = estimate_run(RunPlan.of(dkfsim.load_scenario(radio, overrides=overrides)))
        return sum(v for k, v in est.memory.items() if "on the radio" in k)

    per = RADIO_PLACES_BYTES + RADIO_COPY_BYTES + RADIO_SERIES_BYTES
    assert radio_bytes(["steps=1000"]) == 1001 * 14 * per
    assert radio_bytes(["steps=1000", "medium.bystanders.count=100"]) == 1001 * 104 * per
    assert radio_bytes(["steps=1000", "medium.bystanders=null"]) == 1001 * 4 * per
    two = radio_bytes(["steps=1000", "estimators=[{kind: centralized}, {kind: diffusion_kf}]"])
    assert two == 1001 * 14 * (per + RADIO_COPY_BYTES)


def test_the_api_refuses_them_before_the_run(radio, monkeypatch):
    """dkfsim.run refuses as the CLI does (on a machine that can give a run 16 GiB), before the
    run (which here would take the test process's memory: it is not started)."""
    import dkfsim.engine.driver as driver

    def never(*_args, **_kw):
        raise AssertionError("the run was started")
    monkeypatch.setattr(resources, "available_memory", lambda: 16 << 30)
    monkeypatch.setattr(driver, "simulate", never)
    with pytest.raises(ResourceError, match=r"69 GiB of memory \(positions of 10004 vehicles on the radio"):
        dkfsim.run(dkfsim.load_scenario(radio, overrides=MANY[1::2]))


def test_a_waiting_room_of_2_to_the_40_packets_runs_in_bounded_memory(tmp_path):
    """links.default.queue {packets: 2**40} (the schema's maximum) on paper case 1: validated and
    run as any other room, in a few hundred MB (it was a 32 TiB MemoryError traceback)."""
    args = [CASE1, "--set", "steps=20", "--set", "links.default.rate=1e6",
            "--set", "links.default.queue={packets: 1099511627776}"]
    dkfsim_cli("validate", *args).ok()
    out = tmp_path / "out"
    dkfsim_cli("run", *args[:1], "--out", out, *args[1:], env={"DKFSIM_KERNELS": "numpy"}).ok(memory_mb=600)
    assert (out / "summary.json").exists()
