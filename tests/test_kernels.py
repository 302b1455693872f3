"""The compiled (numba) and pure-numpy kernel paths compute the same estimates.

The two paths evaluate the same formulas in different summation orders (the
numba window kernel runs each node from its own earliest changed row, the
numpy one batches all nodes; LU by hand against LAPACK), so they agree to
rounding, not bit for bit.  Tolerances, norm-wise relative error per row:
``x_local``/``x_final`` <= 1e-10 (a well-conditioned 3x3 solve per row, error
~1e-15 per step, and the filter is contractive); ``x_fused``/``P_fused``
<= 1e-8, because the fusion weights solve a KKT system whose ``Xi`` block is
singular at zero latency (every node holds the same information) and is only
regularised at 1e-8 relative (docs/design.md §7): rounding differences in
``Xi`` are amplified by up to ~1e8 in ``Gamma``, bounded by the
regularisation.  The zero-latency case below is that worst case.  The
arrival log and every packet count must be identical: the protocol does not
depend on the kernel path.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import scc_digraph_edges, scenario, tree_edges

import dkfsim
from dkfsim.core.backend import Backend


def rowwise_rel_err(a: np.ndarray, b: np.ndarray) -> float:
    """max over rows of ||a_r - b_r|| / ||b_r|| (rows: the leading axis)."""
    a = a.reshape(a.shape[0], -1)
    b = b.reshape(b.shape[0], -1)
    den = np.maximum(np.linalg.norm(b, axis=1), 1e-300)
    return float(np.max(np.linalg.norm(a - b, axis=1) / den))


CASES = {
    "random_tree": dict(n=9, nx=3, edges=tree_edges(9, 11), latency={"model": "uniform_steps", "d_t": 2}),
    "random_tree_paper_weights": dict(n=8, edges=tree_edges(8, 5), weights="paper",
                                      latency={"model": "uniform_steps", "d_t": 3}, fusion="diagonal"),
    "digraph_flood": dict(n=7, nx=3, directed=True, edges=scc_digraph_edges(7, 3), protocol="flood",
                          latency={"model": "uniform_steps", "d_t": 2}),
    "short_buffer": dict(n=8, edges=tree_edges(8, 2), buffer_length=2,
                         latency={"model": "uniform_steps", "d_t": 3}),
    "loss": dict(n=8, nx=3, edges=tree_edges(8, 4), loss=0.3, latency={"model": "uniform_steps", "d_t": 2}),
    "zero_latency": dict(n=6, nx=3),
    "no_fusion": dict(n=9, nx=3, edges=tree_edges(9, 7), fusion="none", latency={"model": "uniform_steps", "d_t": 2}),
}


def _run(d, kernels, monkeypatch, save="full"):
    monkeypatch.setenv("DKFSIM_KERNELS", kernels)
    res = dkfsim.run(dkfsim.load_scenario(d), save=save)
    assert res.info["kernels"] == kernels
    return res


def _compare(d, monkeypatch):
    a = _run(d, "numba", monkeypatch)
    b = _run(d, "numpy", monkeypatch)
    for key, tol in (("x_local", 1e-10), ("x_final", 1e-10), ("P_local", 1e-10),
                     ("x_fused", 1e-8), ("P_fused", 1e-8)):
        if key in b.arrays:
            err = rowwise_rel_err(a.arrays[key], b.arrays[key])
            assert err <= tol, f"{key}: numba vs numpy {err:.2e} > {tol:.0e}"
    assert np.array_equal(a.arrays["arrival"], b.arrays["arrival"])
    for key in ("sent", "delivered", "lost", "late", "duplicates", "stale"):
        assert a.counts.get(key) == b.counts.get(key), key
    assert a.info["events"] == b.info["events"]          # (what a trial measures: on either path)
    return a, b


@pytest.mark.parametrize("case", list(CASES))
def test_numba_and_numpy_paths_agree(case, monkeypatch):
    kw = dict(CASES[case])
    _compare(scenario(steps=50, seed=3, **kw), monkeypatch)


def test_paths_agree_with_crashes_and_loss(monkeypatch):
    d = scenario(8, nx=3, edges=tree_edges(8, 9), steps=50, loss=0.2,
                 latency={"model": "uniform_steps", "d_t": 2})
    d["faults"] = {"crashes": [{"node": 2, "start": 0.08, "end": 0.21}, {"node": 5, "start": 0.3, "end": 0.36}]}
    a, _ = _compare(d, monkeypatch)
    assert a.arrays["crashed"].any()          # the crashes happened


@pytest.mark.parametrize("overrides", [
    ["links.default.latency={model: exponential, mean: 0.02}", "links.d_t=4"],
    ["links.default.rate=1.0e6", "links.default.queue={packets: 20}",
     "links.default.background={arrivals: poisson, packets_per_second: 50, size: 250}"],
], ids=["exponential", "rate-limited"])
def test_a_trial_measures_the_same_events_on_either_path(overrides, monkeypatch):
    """A resource estimate's trial runs compiled when the kernels are on disk, else on the numpy
    kernels (nothing to compile): the events it measures are the same either way."""
    sc = dkfsim.load_scenario(Path(__file__).resolve().parents[1] / "scenarios" / "paper_case1.yaml",
                              overrides=["steps=80", *overrides])
    a, b = (_run(sc, kernels, monkeypatch, save="summary") for kernels in ("numba", "numpy"))
    assert a.info["events"] == b.info["events"] and a.info["events"]["packets"] > 1000


def test_a_trial_runs_compiled_only_when_the_kernels_are_on_disk(tmp_path):
    """:func:`~dkfsim.engine.driver.trial_backend`: compiled with numba's cache holding every
    kernel a trial runs; the numpy kernels when one module of them is not there (it would compile
    for seconds: a refusal answers before that); the environment's choice on a spatial radio."""
    from conftest import numba_cache_but
    case1 = Path(__file__).resolve().parents[1] / "scenarios" / "paper_case1.yaml"
    highway = case1.parent / "highway_its_g5.yaml"
    code = ("import sys, dkfsim; from dkfsim.engine.driver import trial_backend; "
            "print(*(trial_backend(dkfsim.load_scenario(p)).kernels for p in sys.argv[1:]))")

    def backends(cache: Path | None) -> list[str]:
        env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "DKFSIM_KERNELS")}
        if cache is not None:
            env["NUMBA_CACHE_DIR"] = str(cache)
        out = subprocess.run([sys.executable, "-c", code, str(case1), str(highway)], capture_output=True,
                             text=True, env=env, timeout=120)
        assert out.returncode == 0, out.stderr[-2000:]
        return out.stdout.split()
    assert backends(numba_cache_but(tmp_path / "a", "nothing")) == ["numba", "numba"]
    assert backends(numba_cache_but(tmp_path / "b", "tree_kernels")) == ["numpy", "numba"]
    assert backends(tmp_path / "empty") == ["numpy", "numba"]


def test_short_buffer_case_has_late_information(monkeypatch):
    """The short-buffer case exercises late contributions (else it tests nothing more)."""
    a = _run(scenario(steps=50, seed=3, **CASES["short_buffer"]), "numba", monkeypatch)
    assert a.counts["late"] > 0


def test_numba_path_is_bit_identical_run_to_run(monkeypatch):
    d = scenario(steps=40, seed=3, **CASES["random_tree"])
    a = _run(d, "numba", monkeypatch, save="estimates")
    b = _run(d, "numba", monkeypatch, save="estimates")
    for key in ("x_local", "x_final", "x_fused", "P_fused"):
        assert np.array_equal(a.arrays[key], b.arrays[key]), key


def test_kernels_switch_is_recorded_in_the_summary(monkeypatch, tmp_path):
    res = _run(scenario(4, steps=5), "numpy", monkeypatch, save="summary")
    res.save(tmp_path / "out")
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["kernels"] == "numpy" and summary["exchange"] == "masks"
    assert summary["backend"] == {"kernels": "numpy"}
    assert dkfsim.load_run(tmp_path / "out").info["backend"] == summary["backend"]


@pytest.mark.parametrize("env, expect", [
    ({}, "numba"),
    ({"DKFSIM_KERNELS": "numpy"}, "numpy"),
    ({"DKFSIM_KERNELS": " NumPy "}, "numpy"),
])
def test_the_backend_is_what_the_environment_asks_for(env, expect, monkeypatch):
    monkeypatch.delenv("DKFSIM_KERNELS", raising=False)
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    b = Backend.from_environment()
    assert b.kernels == expect and b.compiled == (expect == "numba")


@pytest.mark.slow
def test_threads_starting_together_compile_the_kernels_once():
    """Runs in threads (a Dask worker with threads, a notebook) may reach the first filter at
    the same instant; each must get the compiled kernels, none may jit a jitted function."""
    code = """
import threading
from dkfsim.estimators import kernels
go, errors = threading.Barrier(16), []
def start():
    go.wait()
    try:
        kernels.compiled()
    except Exception as exc:
        errors.append(repr(exc))
threads = [threading.Thread(target=start) for _ in range(16)]
[t.start() for t in threads]
[t.join() for t in threads]
assert not errors, errors[0]
assert all(hasattr(getattr(kernels, name), "py_func") for name in kernels._KERNELS)
"""
    for _ in range(5):
        p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                           env={**os.environ, "DKFSIM_KERNELS": "numba"})
        assert p.returncode == 0, p.stderr[-2000:]


def test_batched_filter_paths_agree(monkeypatch):
    """The centralized and local-only baselines' filter: one compiled call or K numpy steps."""
    from dkfsim.estimators.window import batched_filter
    rng = np.random.default_rng(3)
    K, b, nx = 200, 4, 3
    T = 0.01
    Phi = np.array([[1, T, T * T / 2], [0, 1, T], [0, 0, 1]])
    H = rng.normal(size=(b, 1, nx))
    Omega = np.einsum("bki,bkj->bij", H, H) * 2.0
    Theta = rng.normal(size=(K, b, nx))
    out = {}
    for path in ("numba", "numpy"):
        monkeypatch.setenv("DKFSIM_KERNELS", path)
        out[path] = batched_filter(Phi, np.eye(nx), np.zeros(nx), np.eye(nx), Omega, Theta)
        out[path + "_rows"] = batched_filter(Phi, np.eye(nx), np.zeros(nx), np.eye(nx),
                                             np.broadcast_to(Omega, (K, b, nx, nx)), Theta)
    for suffix in ("", "_rows"):
        xa, Pa = out["numba" + suffix]
        xb, Pb = out["numpy" + suffix]
        assert rowwise_rel_err(xa, xb) <= 1e-10
        assert rowwise_rel_err(Pa, Pb) <= 1e-10


@pytest.mark.slow
def test_kernels_taking_namedtuples_load_from_the_disk_cache_in_a_new_process():
    """The kernels take module-level namedtuples of arrays; numba must still load them from its
    disk cache in a new process (a local namedtuple type, or a step from another module,
    would compile them again in every process).  A first process compiles or loads them; a
    second one must compile nothing: every kernel a run of paper_case1 calls (window,
    fusion, baseline filter, the tree's bookkeeping, the record port's batch steps, the
    holdings' fold) hit the cache -- those bound to their types (``core.jit.bind``) too."""
    code = """
import json, os, sys
import dkfsim
from dkfsim.estimators import kernels
from dkfsim.model import holdings_kernels as hk
from dkfsim.network import port_kernels as pk
from dkfsim.protocols import tree_kernels as tk
sc = dkfsim.load_scenario(sys.argv[1], overrides=["steps=30"])
dkfsim.run(sc, save="full")
dkfsim.run(sc, save="estimates")
stats = {}
for mod, names in ((kernels, ("window_rows", "xi_rows", "filter_rows")),
                   (tk, ("measure", "receive", "flush")), (pk, ("hand_over", "arrange", "peek", "tally")),
                   (hk, ("fold_masks",))):
    for name in names:
        d = getattr(mod, name)
        stats[name] = [sum(d.stats.cache_hits.values()), sum(d.stats.cache_misses.values())]
print(json.dumps(stats))
"""
    env = {k: v for k, v in os.environ.items() if not k.startswith("DKFSIM_")}
    case = str(Path(__file__).resolve().parents[1] / "scenarios" / "paper_case1.yaml")
    for _attempt in ("first", "second"):
        p = subprocess.run([sys.executable, "-c", code, case], capture_output=True, text=True, timeout=600, env=env)
        assert p.returncode == 0, p.stderr[-2000:]
    stats = json.loads(p.stdout.strip().splitlines()[-1])
    assert all(hits > 0 and misses == 0 for hits, misses in stats.values()), stats


@pytest.mark.slow
def test_a_run_compiles_each_kernel_for_arguments_of_one_kind():
    """A kernel is compiled once per distinct argument types (tens of seconds of a first run):
    a constant handed from one kernel to another is typed as its literal value, a Fortran-ordered
    or read-only array as a type of its own, and each made a second compile of the callee and its
    callees.  After runs of paper case 1, of the highway on 802.11p and on the sidelink (its
    bystanders' presence made a Fortran-ordered array), and of the one-domain channel, no kernel
    was compiled for a literal, a non-C-ordered array or a read-only one."""
    from numba.core import types

    from dkfsim.estimators import kernels
    from dkfsim.model import holdings_kernels as hk
    from dkfsim.network import port_kernels as pk
    from dkfsim.network import radio_kernels as rk
    from dkfsim.protocols import tree_kernels as tk
    root = Path(__file__).resolve().parents[1] / "scenarios"
    for name, overrides in (("paper_case1.yaml", ["steps=20"]), ("channel_its_g5.yaml", ["steps=5"]),
                            ("highway_its_g5.yaml", ["steps=3"]),
                            ("highway_its_g5.yaml", ["steps=3", "medium.access.kind=sps"])):
        dkfsim.run(dkfsim.load_scenario(root / name, overrides=overrides))

    def odd(t) -> bool:
        if isinstance(t, types.Literal):
            return True
        if isinstance(t, types.Array):
            return t.layout != "C" or not t.mutable
        if isinstance(t, types.BaseTuple):
            return any(odd(e) for e in t.types)
        return False

    seen = 0
    for mod in (kernels, hk, pk, rk, tk):
        compiled = mod.compiled()
        for kname in vars(compiled):
            d = getattr(compiled, kname)
            for sig in getattr(d, "signatures", ()) if hasattr(d, "py_func") else ():
                seen += 1
                assert not any(odd(a) for a in sig), f"{mod.__name__}.{kname} compiled for {sig}"
    assert seen > 20


def test_no_kernel_module_calls_another_files_kernels():
    """numba's disk cache keys a kernel by its own file only: a kernel calling a step of another
    file would keep stale code after an edit there.  So every kernel module (one that compiles
    with ``LazyKernels``) imports no other kernel module: what two of them share goes through
    Python (a protocol hands its gains to the holdings' fold; the port hands its packets to the
    protocol's kernels as arrays).  Checked on the source of every module of the package, so a
    new kernel module cannot break it unseen."""
    import ast
    root = Path(__file__).resolve().parents[1]
    kernel_modules = {str(p.relative_to(root))[:-3].replace("/", "."): p for p in (root / "dkfsim").rglob("*.py")
                      if "= LazyKernels(" in p.read_text()}
    assert {"dkfsim.protocols.tree_kernels", "dkfsim.network.port_kernels", "dkfsim.model.holdings_kernels",
            "dkfsim.estimators.kernels"} <= set(kernel_modules)
    for name, path in kernel_modules.items():
        tree = ast.parse(path.read_text())
        imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module}
        imported |= {f"{node.module}.{a.name}" for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)
                     and node.module for a in node.names}
        assert not (imported & (set(kernel_modules) - {name})), f"{name} imports another kernel module"
