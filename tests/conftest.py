"""Shared scenario builders for the dkfsim correctness tests.

Scenarios are built as plain dicts (the schema of docs/scenarios.md) with
explicit edge lists where a test needs to know the graph (diameters, paths),
so that the expected values never depend on the engine's graph generators.
The engine is imported lazily: the reference self-tests run without it.
"""

from __future__ import annotations

import copy
import os
import sys
from collections import deque
from pathlib import Path

import numpy as np
import pytest
from interrupts import pytest_configure  # noqa: F401  (Ctrl-C and SIGTERM stop every process: issue 34)

# A fresh Python process the tests start (the CLI, a tool, a pool's worker) compiles dkfsim from
# source when Python may not write bytecode (PYTHONDONTWRITEBYTECODE, set on some machines, CI's
# among them): the suite lets it be written once into the checkout's __pycache__ (git-ignored),
# 0.3 s less per process started.
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
sys.dont_write_bytecode = False

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
from slow_tier import read_list  # noqa: E402  (tools/: the list's writer reads it too)

#: Tests in the slow tier by measurement (tools/slow_tier.py): over the fast tier's per-test budget.
SLOW_BY_TIME = set(read_list())


def pytest_collection_modifyitems(items):
    """Mark ``slow`` the tests tests/slow_tests.txt lists (``slow_by_time`` too: what
    tools/slow_tier.py measures again), and those using the hostile tier's ``legit`` folders (a
    run, a Monte Carlo and a sweep with their reports and figures: 20 s to make, once per test
    process)."""
    for item in items:
        if item.nodeid in SLOW_BY_TIME:
            item.add_marker(pytest.mark.slow)
            item.add_marker(pytest.mark.slow_by_time)
        elif "legit" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.slow)


# ----------------------------------------------------------------------------
# models and sensors
# ----------------------------------------------------------------------------

T2 = 0.1


def linear2_model(q=1.0, T=T2):
    """Nearly-constant-velocity model, 2 states."""
    return {
        "kind": "linear",
        "T": T,
        "Phi": [[1.0, T], [0.0, 1.0]],
        "Q": [[q * T ** 3 / 3, q * T ** 2 / 2], [q * T ** 2 / 2, q * T]],
    }


PRIOR2 = {"mean": [0.0, 1.0], "cov": [[1.0, 0.2], [0.2, 0.5]]}

# A mix of scalar and 2-dimensional sensors of a 2-state system.
SENSORS2 = [
    {"H": [[1.0, 0.0]], "R": [[0.5]]},
    {"H": [[0.0, 1.0]], "R": [[0.8]]},
    {"H": [[1.0, 0.0], [0.0, 1.0]], "R": [[0.6, 0.1], [0.1, 0.9]]},
    {"H": [[1.0, 0.5]], "R": [[1.2]]},
    {"H": [[1.0, 0.0]], "R": [[2.0]]},
    {"H": [[0.5, 1.0], [1.0, -0.3]], "R": [[1.0, 0.0], [0.0, 0.4]]},
    {"H": [[0.0, 1.0]], "R": [[0.3]]},
    {"H": [[1.0, -1.0]], "R": [[0.7]]},
]

CA_MODEL = {"kind": "constant_acceleration", "T": 0.01,
            "Q": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}
PRIOR3 = {"mean": [0.0, 0.0, 0.0], "cov": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}
SENSORS3 = [
    {"H": [[1.0, 0.0, 0.0]], "R": [[0.8]]},
    {"H": [[0.0, 1.0, 0.0]], "R": [[1.0]]},
    {"H": [[0.0, 0.0, 1.0]], "R": [[2.0]]},
    {"H": [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], "R": [[0.5, 0.0], [0.0, 1.5]]},
    {"H": [[0.0, 1.0, 0.0]], "R": [[0.5]]},
    {"H": [[1.0, 0.0, 0.0]], "R": [[0.1]]},
]


def sensors(n, nx=2):
    pool = SENSORS2 if nx == 2 else SENSORS3
    out = []
    for i in range(n):
        s = copy.deepcopy(pool[i % len(pool)])
        s["name"] = f"s{i}"
        out.append(s)
    return out


# ----------------------------------------------------------------------------
# graphs (built here, so the tests know them independently of the engine)
# ----------------------------------------------------------------------------

def tree_edges(n, seed):
    """A uniformly random labelled tree on n nodes (Pruefer decoding)."""
    rng = np.random.default_rng(seed)
    if n == 2:
        return [[0, 1]]
    seq = [int(v) for v in rng.integers(0, n, size=n - 2)]
    degree = [1] * n
    for v in seq:
        degree[v] += 1
    edges = []
    for v in seq:
        leaf = min(u for u in range(n) if degree[u] == 1)
        edges.append([leaf, v])
        degree[leaf] -= 1
        degree[v] -= 1
    u, w = [x for x in range(n) if degree[x] == 1]
    edges.append([u, w])
    return edges


def scc_digraph_edges(n, seed, chords=None):
    """A random strongly connected digraph: a random directed Hamiltonian
    cycle plus random chords (no self loops, no duplicates)."""
    rng = np.random.default_rng(seed)
    perm = [int(v) for v in rng.permutation(n)]
    edges = {(perm[j], perm[(j + 1) % n]) for j in range(n)}
    if chords is None:
        chords = n // 2
    tries = 0
    target = len(edges) + chords
    while len(edges) < target and tries < 1000:
        u, v = (int(a) for a in rng.integers(0, n, size=2))
        tries += 1
        if u != v:
            edges.add((u, v))
    return sorted([list(e) for e in edges])


def distances(n, edges, directed):
    """All-pairs hop distances dist[a][b] (a -> b) by BFS."""
    adj = [[] for _ in range(n)]
    for u, v in edges:
        adj[u].append(v)
        if not directed:
            adj[v].append(u)
    dist = np.full((n, n), -1, dtype=int)
    for s in range(n):
        dist[s, s] = 0
        q = deque([s])
        while q:
            a = q.popleft()
            for b in adj[a]:
                if dist[s, b] < 0:
                    dist[s, b] = dist[s, a] + 1
                    q.append(b)
    assert (dist >= 0).all(), "graph not (strongly) connected"
    return dist


def diameter(n, edges, directed):
    return int(distances(n, edges, directed).max())


def tree_path(n, edges, a, b):
    """Nodes on the tree path from a to b (inclusive)."""
    adj = [[] for _ in range(n)]
    for u, v in edges:
        adj[u].append(v)
        adj[v].append(u)
    parent = {a: None}
    q = deque([a])
    while q:
        u = q.popleft()
        for v in adj[u]:
            if v not in parent:
                parent[v] = u
                q.append(v)
    path = [b]
    while path[-1] != a:
        path.append(parent[path[-1]])
    return path[::-1]


# ----------------------------------------------------------------------------
# scenarios
# ----------------------------------------------------------------------------

def scenario(n=6, *, nx=2, edges=None, generator="edges", params=None, directed=False,
             steps=60, latency=None, loss=0.0, overrides=(), links_d_t=None,
             protocol="tree", weights="unit", buffer_length="auto", fusion="matrix",
             seed=1, name="t"):
    """A scenario dict.  Default: the 2-state model, a random tree (explicit
    edges), zero latency."""
    if latency is None:
        latency = {"model": "constant", "value": 0.0}
    topo = {"directed": directed, "generator": generator}
    if generator == "edges":
        if edges is None:
            edges = tree_edges(n, seed + 100)
        topo["edges"] = [list(e) for e in edges]
    if params is not None:
        topo["params"] = dict(params)
    return {
        "name": name,
        "seed": seed,
        "steps": steps,
        "model": linear2_model() if nx == 2 else copy.deepcopy(CA_MODEL),
        "prior": copy.deepcopy(PRIOR2 if nx == 2 else PRIOR3),
        "sensors": sensors(n, nx),
        "topology": topo,
        "links": {"default": {"latency": dict(latency), "loss": loss},
                  "overrides": [copy.deepcopy(o) for o in overrides],
                  "d_t": links_d_t},
        "protocol": protocol,
        "weights": weights,
        "buffer_length": buffer_length,
        "fusion": fusion,
        "baselines": ["centralized"],
    }


def numba_cache_but(folder: Path, cold: str) -> Path:
    """A ``NUMBA_CACHE_DIR`` in ``folder`` holding this checkout's compiled kernels (copied from
    numba's cache beside the sources) but those of the module ``cold`` (a file stem, e.g.
    ``holdings_kernels``): a run with it compiles that module alone, a few seconds where every
    kernel cold is 35 s of CPU.  (numba's layout for NUMBA_CACHE_DIR: one folder per source folder,
    ``<name>_<sha1 of its absolute path>``.  Were it to change, the run compiles everything: slower,
    not wrong.)"""
    import hashlib
    import shutil

    import dkfsim
    dkfsim.run(Path(__file__).resolve().parents[1] / "scenarios" / "paper_case1.yaml", steps=3)  # (loaded: cached)
    cache = folder / "numba_cache"
    for src in Path(dkfsim.__file__).parent.rglob("__pycache__/*.nb[ic]"):
        if src.name.startswith(cold + "."):
            continue
        home = os.path.dirname(os.path.abspath(src.parent))           # the sources' folder
        sub = cache / f"{os.path.basename(home)}_{hashlib.sha1(home.encode()).hexdigest()}"
        sub.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, sub / src.name)
    return cache


def import_dkfsim():
    import dkfsim  # noqa: F401  (a failure here is a failure of the test)
    return dkfsim


class Run:
    """A finished run: ``arrays`` as numpy arrays, ``counts``, the result."""

    def __init__(self, res, sc):
        self.res = res
        self.sc = sc
        self.arrays = {k: np.asarray(v) for k, v in res.arrays.items()}
        self.counts = res.counts

    def __getitem__(self, key):
        return self.arrays[key]


def run_scenario(sc, overrides=()):
    dk = import_dkfsim()
    loaded = dk.load_scenario(copy.deepcopy(sc), overrides=list(overrides))
    return Run(dk.run(loaded), sc)


@pytest.fixture(scope="session")
def dkfsim():
    return import_dkfsim()


@pytest.fixture
def isolated_registries():
    """Snapshot every registry and the loaded plugin modules; restore them after the test, so
    what a test registers (a plugin, a deliberately broken estimator) is never seen by others."""
    import sys

    from dkfsim.core import registry
    registry.ensure_registered()       # (the built-ins register at the first read: before the snapshot)
    saved = {name: (dict(reg._entries), dict(reg._aliases)) for name, reg in registry.REGISTRIES.items()}
    modules = set(sys.modules)
    yield
    for name, reg in registry.REGISTRIES.items():
        reg._entries, reg._aliases = saved[name]
    for m in set(sys.modules) - modules:
        if m.startswith("dkfsim_plugin_") or m.startswith("dkfsim_test_entry"):
            del sys.modules[m]
