#!/usr/bin/env python
"""The vehicle traffic of the highway scenario (issue 32): SUMO floating-car data, regenerated.

A straight highway, 3 km long, 3 lanes in each direction, speed limit 120 km/h: ``netgenerate``
builds it (a two-node grid: edge ``A0B0`` eastbound, x from 0 to 3000 m, lanes at y = -1.6, -4.8,
-8.0 m; edge ``B0A0`` westbound, lanes at y = +1.6, +4.8, +8.0 m), ``randomTrips.py`` makes the
trips of each direction (ids ``east<n>``, ``west<n>``; each drives the whole 3 km) departing at
uniformly random times at two rates, and ``sumo`` runs each headless (fixed ``--seed``, ``--step-length 0.1``) for a 300 s warm-up and a
60 s window, of which it writes floating-car data every 1 s (``--fcd-output``, x/y, the attributes
``x,y,angle,speed,lane``).  Two files come out, with the window's time shifted to start at 0
(file time = SUMO time - 300 s) and SUMO's header comment (date, temporary paths) replaced by a
fixed one, so a rerun writes the same bytes:

``scenarios/data/highway_light.fcd.xml``  about 100 vehicles on the 3 km at once (both directions)
``scenarios/data/highway_dense.fcd.xml``  about 300

and ``scenarios/data/highway.json``: the SUMO version, the commands run, the seeds, the densities
measured in the files (vehicles per km per direction), and for each file the ids of the vehicles
present during the whole window and a group of 12 of them: consecutive eastbound vehicles at
t = 0 (no other vehicle between them, on any lane), the run of 12 that stays the most compact
over the window.  A dkfsim scenario names them as ``{kind: sumo_fcd, file: data/highway_light.fcd.xml,
vehicle: east148}`` (docs/trajectories.md).

Standard library and SUMO only (not dkfsim): run it with a Python that has the ``sumo`` extra of
pyproject.toml (eclipse-sumo 1.28.0; ``make test`` never installs it), e.g.::

    python3 -m venv ../sumoenv && ../sumoenv/bin/pip install eclipse-sumo==1.28.0
    ../sumoenv/bin/python tools/sumo_highway.py [--out scenarios/data]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET
from decimal import Decimal
from pathlib import Path

import sumo

ROOT = Path(__file__).resolve().parents[1]
SUMO_VERSION = "1.28.0"
SUMO_HOME = Path(sumo.__file__).resolve().parent
SEED = 32
LENGTH_M = 3000
LANES = 3
SPEED_LIMIT = 33.33            # m/s: 120 km/h
WARMUP_S = 300                 # a vehicle crosses the 3 km in about 100 s
WINDOW_S = 60
GROUP = 12
#: The two traffic densities: randomTrips' mean insertion period (s) in each direction, chosen
#: for about 100 and 300 vehicles on the road at once (measured: highway.json).
DENSITIES = {"light": 1.8, "dense": 0.65}
#: Each direction's edge, the prefix of its vehicles' ids and randomTrips' seed.
DIRECTIONS = {"eastbound": ("A0B0", "east", SEED), "westbound": ("B0A0", "west", SEED + 1)}
EDGES = {edge: d for d, (edge, _, _) in DIRECTIONS.items()}
MAX_BYTES = 5 << 20

NETGENERATE = ["$SUMO_HOME/bin/netgenerate", "--grid", "--grid.x-number", "2", "--grid.y-number", "1",
               "--grid.x-length", str(LENGTH_M), "--default.lanenumber", str(LANES),
               "--default.speed", str(SPEED_LIMIT), "--no-turnarounds", "--output-file", "highway.net.xml"]


def weights(direction: str) -> str:
    """randomTrips' source and destination weights (``--weights-prefix``) of one direction: its
    edge only (an edge not listed has weight 0)."""
    return f'<edgedata><interval begin="0" end="{WARMUP_S + WINDOW_S + 1}"><edge id="{DIRECTIONS[direction][0]}" ' \
           'value="1"/></interval></edgedata>\n'


def random_trips(name: str, period: float, direction: str) -> list[str]:
    """randomTrips.py's command for density ``name`` in one direction: trips from the start to the
    end of its edge (``--allow-fringe``: the edge both enters and leaves the network), departing at
    uniformly random times (on average one every ``period`` s) until the run's end, inserted at
    full speed on the best lane."""
    _, prefix, seed = DIRECTIONS[direction]
    return ["python", "$SUMO_HOME/tools/randomTrips.py", "--net-file", "highway.net.xml",
            "--weights-prefix", direction, "--output-trip-file", f"{name}.{direction}.trips.xml",
            "--seed", str(seed), "--prefix", prefix, "--begin", "0", "--end", str(WARMUP_S + WINDOW_S + 1),
            "--period", str(period), "--random-depart", "--allow-fringe", "--validate", "--threads", "1",
            "--trip-attributes", 'departLane="best" departSpeed="max"']


def run_sumo(name: str) -> list[str]:
    """sumo's command for density ``name``: FCD every 1 s from the end of the warm-up to the end of
    the window, both included (``--end`` is exclusive)."""
    routes = ",".join(f"{name}.{d}.trips.xml" for d in DIRECTIONS)
    return ["$SUMO_HOME/bin/sumo", "--net-file", "highway.net.xml", "--route-files", routes,
            "--seed", str(SEED), "--step-length", "0.1", "--begin", "0", "--end", str(WARMUP_S + WINDOW_S + 1),
            "--fcd-output", f"{name}.fcd.xml", "--fcd-output.attributes", "x,y,angle,speed,lane",
            "--device.fcd.begin", str(WARMUP_S), "--device.fcd.period", "1",
            "--no-step-log", "--duration-log.disable"]


def execute(argv: list[str], cwd: Path) -> None:
    """Run one recorded command (``$SUMO_HOME`` and ``python`` resolved) in ``cwd``."""
    real = [a.replace("$SUMO_HOME", str(SUMO_HOME)) for a in argv]
    if real[0] == "python":
        real[0] = sys.executable
    env = dict(os.environ, SUMO_HOME=str(SUMO_HOME))
    p = subprocess.run(real, cwd=cwd, env=env, capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"failed ({p.returncode}): {' '.join(argv)}\n{p.stdout[-3000:]}{p.stderr[-3000:]}")


def sumo_version() -> str:
    """The first line of ``sumo --version``; refuses any version but the one the files come from."""
    out = subprocess.run([str(SUMO_HOME / "bin" / "sumo"), "--version"], capture_output=True, text=True,
                         env=dict(os.environ, SUMO_HOME=str(SUMO_HOME))).stdout
    line = out.splitlines()[0].strip()
    if not line.endswith(f" {SUMO_VERSION}"):
        sys.exit(f"{line!r}: the shipped files come from SUMO {SUMO_VERSION} (pip install eclipse-sumo=={SUMO_VERSION})")
    return line


_TIMESTEP = re.compile(r'<timestep time="([0-9]+\.[0-9]+)">')


def shifted(text: str, name: str) -> str:
    """SUMO's FCD output with the window's time starting at 0 and SUMO's header comment (date,
    temporary paths, options) replaced by a fixed one; every other byte as SUMO wrote it."""
    decl, rest = text.split("\n", 1)
    if not decl.startswith("<?xml") or not rest.lstrip().startswith("<!--"):
        sys.exit(f"{name}: unexpected start of SUMO's FCD output")
    rest = rest.split("-->", 1)[1].lstrip()
    if not rest.startswith("<fcd-export"):
        sys.exit(f"{name}: no <fcd-export> after SUMO's header comment")

    def shift(m: re.Match) -> str:
        t = Decimal(m.group(1)) - WARMUP_S
        return f'<timestep time="{t:.2f}">'

    # (no two hyphens in a row: XML forbids them inside a comment)
    header = (f"<!-- dkfsim scenarios/data/{name}: the floating-car data of sumo {SUMO_VERSION}, written by "
              f"tools/sumo_highway.py (commands, seed and vehicle ids: highway.json); time is SUMO's "
              f"minus {WARMUP_S} s (the warm-up), x/y in metres of SUMO's network -->")
    return f"{decl}\n{header}\n{_TIMESTEP.sub(shift, rest)}"


def analyse(path: Path) -> dict:
    """Densities, the vehicles present throughout and the group of 12, from the written file."""
    timesteps = list(ET.parse(path).getroot().iter("timestep"))
    times = [float(ts.get("time")) for ts in timesteps]
    # per timestep: {id: (direction, x)}
    steps = [{v.get("id"): (EDGES[v.get("lane").split("_")[0]], float(v.get("x"))) for v in ts}
             for ts in timesteps]
    if times != [float(t) for t in range(WINDOW_S + 1)]:
        sys.exit(f"{path.name}: timesteps {times[:3]}...{times[-3:]}, not 0..{WINDOW_S} s every 1 s")
    km = LENGTH_M / 1000
    density = {}
    for d in DIRECTIONS:
        counts = [sum(1 for dx in step.values() if dx[0] == d) for step in steps]
        density[d] = {"mean": round(sum(counts) / len(counts) / km, 2), "min": round(min(counts) / km, 2),
                      "max": round(max(counts) / km, 2)}
    present = set(steps[0]).intersection(*steps[1:])
    first = steps[0]
    by_direction = {d: sorted((v for v in present if first[v][0] == d), key=lambda v: -first[v][1])
                    for d in DIRECTIONS}
    # The group: consecutive eastbound vehicles at t = 0 (front to back, every lane), all present
    # throughout; of those runs of 12, the one whose length (first to last, m) is smallest at its widest.
    order = sorted((v for v in first if first[v][0] == "eastbound"), key=lambda v: (-first[v][1], v))
    best = None
    for i in range(len(order) - GROUP + 1):
        run = order[i:i + GROUP]
        if not present.issuperset(run):
            continue
        spans = [max(step[v][1] for v in run) - min(step[v][1] for v in run) for step in steps]
        if best is None or max(spans) < best[0]:
            best = (max(spans), spans[0], run)
    if best is None:
        sys.exit(f"{path.name}: no {GROUP} consecutive eastbound vehicles present throughout")
    data = path.read_bytes()
    return {
        "bytes": len(data),
        "sha256": hashlib.sha256(data).hexdigest(),
        "vehicles_in_file": len(set().union(*steps)),
        "vehicles_on_road_mean": round(sum(map(len, steps)) / len(steps), 1),
        "density_veh_per_km_per_direction": density,
        "group": {"direction": "eastbound", "ids": best[2], "length_m_at_t0": round(best[1], 1),
                  "length_m_max": round(best[0], 1)},
        "present_throughout_count": len(present),
        "present_throughout": {d: ids for d, ids in by_direction.items()},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "scenarios" / "data",
                    help="folder for the two FCD files and highway.json (default: scenarios/data)")
    args = ap.parse_args()
    version = sumo_version()
    args.out.mkdir(parents=True, exist_ok=True)
    commands = [NETGENERATE]
    files = {}
    with tempfile.TemporaryDirectory(prefix="sumo_highway_") as tmp:
        work = Path(tmp)
        execute(NETGENERATE, work)
        for d in DIRECTIONS:
            for suffix in (".src.xml", ".dst.xml"):
                (work / f"{d}{suffix}").write_text(weights(d), encoding="utf-8")
        for name, period in DENSITIES.items():
            out_name = f"highway_{name}.fcd.xml"
            for argv in [*(random_trips(name, period, d) for d in DIRECTIONS), run_sumo(name)]:
                execute(argv, work)
                commands.append(argv)
            text = (work / f"{name}.fcd.xml").read_text(encoding="utf-8")
            (args.out / out_name).write_text(shifted(text, out_name), encoding="utf-8")
            files[out_name] = {"density": name, "insertion_period_s": period, **analyse(args.out / out_name)}
            if files[out_name]["bytes"] > MAX_BYTES:
                sys.exit(f"{out_name}: {files[out_name]['bytes']:,} bytes, over {MAX_BYTES:,}")
    meta = {
        "issue": 32,
        "sumo_version": version,
        "seed": {"sumo": SEED, **{f"randomTrips {d}": seed for d, (_, _, seed) in DIRECTIONS.items()}},
        "road": {"length_m": LENGTH_M, "lanes_per_direction": LANES, "speed_limit_m_s": SPEED_LIMIT,
                 "eastbound": "edge A0B0: x from 0 to 3000 m, lanes at y = -1.6, -4.8, -8.0 m",
                 "westbound": "edge B0A0: x from 3000 to 0 m, lanes at y = 1.6, 4.8, 8.0 m"},
        "window": {"sumo_time_s": [WARMUP_S, WARMUP_S + WINDOW_S], "file_time_s": [0, WINDOW_S], "period_s": 1,
                   "file_time": f"SUMO time - {WARMUP_S} s"},
        "commands": commands,
        "weights_files": {f"{d}{suffix}": weights(d) for d in DIRECTIONS for suffix in (".src.xml", ".dst.xml")},
        "commands_note": ("run in order in a temporary folder holding weights_files after netgenerate, $SUMO_HOME the "
                          "sumo package's folder; tools/sumo_highway.py then shifts each FCD file's time and "
                          "replaces its header comment"),
        "files": files,
    }
    (args.out / "highway.json").write_text(json.dumps(meta, indent=1) + "\n", encoding="utf-8")
    print(f"{version}, seeds {meta['seed']}")
    for argv in commands:
        print("  " + " ".join(f"'{a}'" if " " in a else a for a in argv))
    for out_name, f in files.items():
        d = f["density_veh_per_km_per_direction"]
        print(f"{args.out / out_name}: {f['bytes']:,} bytes, {f['vehicles_on_road_mean']} vehicles on the road, "
              f"{d['eastbound']['mean']} eastbound and {d['westbound']['mean']} westbound per km; "
              f"{f['present_throughout_count']} present throughout; group of {GROUP} (eastbound, "
              f"{f['group']['length_m_at_t0']} m long at t = 0): {' '.join(f['group']['ids'])}")
    print(f"{args.out / 'highway.json'}")


if __name__ == "__main__":
    main()
