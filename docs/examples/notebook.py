# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # dkfsim from a notebook: a run, a Monte Carlo and a sweep
#
# A jupytext "percent" script: open it in Jupyter (`jupytext --to notebook
# docs/examples/notebook.py`, or Jupyter with the jupytext extension) or run it as
# `python docs/examples/notebook.py`. It needs the `notebook` and `plots` extras
# (`pip install 'dkfsim[notebook,plots]'`): pandas, xarray, ipywidgets (the
# progress bars' widget in Jupyter) and matplotlib. It runs from any working
# directory inside or outside the repository, and finds the example scenarios
# beside itself (or in the checkout dkfsim is installed from).
# `tests/test_notebook.py` executes it on every `make test`, with tiny sizes, from
# another directory, so it cannot go stale.
#
# Every result converts to pandas with `to_frame()` -- the tidy columns of the
# files (`run, seed, estimate, component, mse, anees, ...`) -- and the arrays to
# an `xarray.Dataset` with named dimensions (`tick`, `node`, `state`) with
# `to_xarray()`.

# %%
import os
from pathlib import Path

import matplotlib.pyplot as plt

import dkfsim
from dkfsim.report.plots import color_of  # each estimate's colour in every dkfsim figure


def find_repository(marker: str = "scenarios/paper_case1.yaml") -> Path:
    """The dkfsim checkout holding the example scenarios, from any working directory: above
    this file (run as a script), above the installed package (`pip install -e .`), or above
    the working directory (Jupyter, where `__file__` is not defined)."""
    starts = [Path(dkfsim.__file__).resolve().parent, Path.cwd().resolve()]
    if "__file__" in globals():
        starts.insert(0, Path(__file__).resolve().parent)
    for start in starts:
        for folder in (start, *start.parents):
            if (folder / marker).is_file():
                return folder
    raise FileNotFoundError(
        f"the example notebook needs {marker} from the dkfsim repository, and found it above "
        f"none of: {', '.join(str(s) for s in starts)}. The scenarios come with a clone of the "
        "repository, not with the installed package: start the notebook inside a clone.")


ROOT = find_repository()
OUT = Path(os.environ.get("DKFSIM_EXAMPLE_OUT", ROOT / "out" / "notebook"))
OUT.mkdir(parents=True, exist_ok=True)
# Sizes: small enough for a laptop in a minute; the test makes them tiny.
STEPS = int(os.environ.get("DKFSIM_EXAMPLE_STEPS", 300))
RUNS = int(os.environ.get("DKFSIM_EXAMPLE_RUNS", 10))

# %% [markdown]
# ## One run
# `dkfsim.run` takes a scenario file, a mapping or a `Scenario`; `progress=True`
# draws a `tqdm.auto` bar (a widget in Jupyter). The result's repr is its table.

# %%
scenario = dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml",
                                overrides=[f"steps={STEPS}", "estimators=[{kind: centralized}]"])
res = dkfsim.run(scenario, progress=True)
res

# %%
rows = res.to_frame()          # the rows of rows.csv
rows[["estimate", "component", "mse", "anees", "messages_per_tick"]]

# %%
ds = res.to_xarray()           # dims: tick (coordinate time, s), node, state, ...
ds

# %%
fig, ax = plt.subplots(figsize=(7, 3))
ax.plot(ds.time, ds.truth.sel(state="position"), color="0.6", lw=3, label="truth")
ax.plot(ds.time, ds.x_fused.sel(state="position"), color=color_of("fused"), label="fused")
ax.plot(ds.time, ds.x_local.sel(state="position", node=0), color=color_of("local"), ls=":",
        label="local, node 0")
ax.set_xlabel("time [s]")
ax.set_ylabel("position [m]")
ax.legend()

# %% [markdown]
# ## A small Monte Carlo
# Run `r` uses seed `derive_seed(seed, r)`; `to_frame()` gives the rows of
# `runs.csv`, `to_xarray()` the pooled curves (MSE per tick with its 95 %
# interval, mean NEES) on (`estimate`, `tick`, `state`).

# %%
mc = dkfsim.montecarlo(scenario, runs=RUNS, progress=True)
mc

# %%
runs = mc.to_frame()
table = runs.groupby(["estimate", "component"], sort=False)["mse"].agg(["mean", "std", "count"])
table

# %%
# The frame holds the numbers of the summary: the same mean per estimate and component.
summary = mc.summary()["estimates"]
for (estimate, component), mean in table["mean"].items():
    assert abs(mean - summary[estimate]["mse"][component]) <= 1e-12 * max(1.0, abs(mean))

# %%
curves = mc.to_xarray()
fig, ax = plt.subplots(figsize=(7, 3))
for name in ("fused", "centralized", "local"):
    c = curves.sel(estimate=name, state="position")
    col = color_of(name, curves.estimate.values)
    ax.plot(c.time, c.mse, color=col, label=name)
    ax.fill_between(c.time, c.mse_ci_lo.clip(min=0), c.mse_ci_hi, color=col, alpha=0.2)
ax.set_yscale("log")
ax.set_xlabel("time [s]")
ax.set_ylabel("position MSE [m$^2$]")
ax.set_title(f"MSE per tick over {RUNS} runs (95 % interval shaded)")
ax.legend()

# %% [markdown]
# ## A sweep
# A grid of scenario keys x Monte Carlo runs into a resumable SQLite file. The
# stored rows read back as a DataFrame with the grid columns first; the summary
# gives, per grid point and estimate, the mean with its 95 % interval -- the
# table `dkfsim sweep` writes beside the database and `dkfsim plot DB --x KEY` draws.

# %%
sweep = {"scenario": str(ROOT / "scenarios" / "paper_case1.yaml"),
         "grid": {"links.default.latency.d_t": [0, 2, 4]},
         "set": [f"steps={STEPS}", "estimators=[{kind: centralized}, {kind: no_buffer}]"],
         "runs": max(2, RUNS // 2)}
report = dkfsim.sweep(sweep, db=OUT / "delay.sqlite", jobs=1, progress=True)
report                          # what ran; the rows are in the database

# %%
rows = report.to_frame()        # the export's table: grid columns, then the tidy columns
rows.head()

# %%
points = report.summary()       # = <database stem>.summary.csv of `dkfsim sweep`
pos = points[points.component == "position"]
fig, ax = plt.subplots(figsize=(6, 3))
for name, g in pos.groupby("estimate", sort=False):
    ax.plot(g["links.default.latency.d_t"], g.mse, marker="o", label=name)
    ax.fill_between(g["links.default.latency.d_t"], g.mse_ci95_lo, g.mse_ci95_hi, alpha=0.2)
ax.set_xlabel("per-hop delay bound d_t [ticks]")
ax.set_ylabel("position MSE [m$^2$]")
ax.set_title("MSE against the delay bound (95 % interval over runs)")
ax.legend()
