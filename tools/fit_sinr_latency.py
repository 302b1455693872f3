#!/usr/bin/env python
"""Fit the ``cellular_sinr`` latency model on three CICV5G drives and KS-test it on the fourth.

The CICV5G drives record, every ~55 ms, the car's 5G round trip car -> cloud -> car
(``delay(ms)``) beside the SINR the modem reported (``sinr(db)``).  The fit pools the
round trips of the three fitting drives, splits them by SINR bin and stores each bin's
empirical quantiles (numpy's linear method) at levels ``k / 200``; the model draws by linear
interpolation between them (``dkfsim.components.latency.sinr_latency_ms``).

The test: for every row of the held-out drive, ``DRAWS_PER_ROW`` draws of the fitted model
at that row's SINR (numpy ``default_rng(SEED)``); scipy's two-sample Kolmogorov-Smirnov test of
the held-out round trips against those draws, per bin and overall.

Usage::

    python tools/fit_sinr_latency.py            # print the fit's KS table
    python tools/fit_sinr_latency.py --splits   # and the overall KS of each leave-one-out split
    python tools/fit_sinr_latency.py --write    # (re)write dkfsim/data/cicv5g/sinr_latency_fit.json
    python tools/fit_sinr_latency.py --check    # exit 1 unless the shipped file equals the fit

docs/latency_models.md ("cellular_sinr") quotes the table; tests/test_cellular_sinr.py
recomputes the fit and checks the shipped file and the docs against it.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys

import numpy as np
from scipy import stats

from dkfsim.components.latency import SINR_FIT_FILE, sinr_latency_ms
from dkfsim.core.datafiles import dataset_path, read_table
from dkfsim.core.folders import write_text

FIT_DRIVES = ("cicv5g/arterial_n8_v70_run03", "cicv5g/s2w_n78_v50_run03", "cicv5g/south_n8_v10_02")
TEST_DRIVE = "cicv5g/urban_n8_v30_run01"
#: SINR bin edges (dB): < 10, [10, 15), >= 15.
BIN_EDGES_DB = (10.0, 15.0)
LEVELS = 200
DRAWS_PER_ROW = 10
SEED = 0


def drive(name: str) -> tuple[np.ndarray, np.ndarray, str]:
    """``(delay_ms, sinr_db, sha256)`` of a shipped drive, in file order."""
    path = dataset_path(name)
    table = read_table(path)
    delay = np.array([v for _, v in table.floats(table.column_index("delay(ms)"))])
    sinr = np.array([v for _, v in table.floats(table.column_index("sinr(db)"))])
    return delay, sinr, hashlib.sha256(path.read_bytes()).hexdigest()


def bin_names() -> list[str]:
    e = BIN_EDGES_DB
    return [f"< {e[0]:g} dB"] + [f"{a:g}-{b:g} dB" for a, b in zip(e[:-1], e[1:])] + [f">= {e[-1]:g} dB"]


def fit(fit_drives=FIT_DRIVES, test_drive=TEST_DRIVE) -> dict:
    """The fit, its provenance and its KS test, as the JSON the model reads."""
    rows = {name: drive(name) for name in tuple(fit_drives) + (test_drive,)}
    delay = np.concatenate([rows[n][0] for n in fit_drives])
    sinr = np.concatenate([rows[n][1] for n in fit_drives])
    which = np.searchsorted(BIN_EDGES_DB, sinr, side="right")
    levels = np.arange(LEVELS + 1) / LEVELS
    bins = []
    for b, name in enumerate(bin_names()):
        sample = delay[which == b]
        if len(sample) == 0:
            raise SystemExit(f"SINR bin {name} has no fitting rows")
        bins.append({"sinr": name, "fit_rows": int(len(sample)),
                     "quantiles_ms": [float(q) for q in np.quantile(sample, levels)]})
    out = {
        "model": "cellular_sinr",
        "what": "5G round trip car -> cloud -> car (ms) by the SINR the car's modem reported: a "
                "cellular (V2N) link, not a car-to-car one",
        "source": "CICV5G dataset (GitHub zxr805/CICV5G, DOI 10.5281/zenodo.17475688), CC BY 4.0",
        "tool": "tools/fit_sinr_latency.py",
        "column": "delay(ms)", "sinr_column": "sinr(db)",
        "fit_drives": list(fit_drives), "test_drive": test_drive,
        "sha256": {n: rows[n][2] for n in tuple(fit_drives) + (test_drive,)},
        "bin_edges_db": list(BIN_EDGES_DB),
        "levels": [float(x) for x in levels],
        "bins": bins,
    }
    out["ks"] = ks_test(out, *rows[test_drive][:2])
    return out


def ks_test(model: dict, delay: np.ndarray, sinr: np.ndarray) -> dict:
    """Two-sample KS of the held-out round trips against the model's draws at their SINRs."""
    rng = np.random.default_rng(SEED)
    sinr_draws = np.repeat(sinr, DRAWS_PER_ROW)
    u = np.minimum(1.0 - rng.random(len(sinr_draws)), 1.0 - 2.0 ** -53)
    draws = sinr_latency_ms(u, sinr_draws, model)
    which, which_draws = (np.searchsorted(BIN_EDGES_DB, s, side="right") for s in (sinr, sinr_draws))

    def one(sel, sel_draws, label):
        res = stats.ks_2samp(delay[sel], draws[sel_draws])
        return {"sinr": label, "test_rows": int(sel.sum()), "D": float(res.statistic),
                "p": float(res.pvalue)}

    out = {"draws_per_row": DRAWS_PER_ROW, "seed": SEED,
           "overall": one(np.ones(len(delay), bool), np.ones(len(draws), bool), "all")}
    out["bins"] = [one(which == b, which_draws == b, name) for b, name in enumerate(bin_names())
                   if (which == b).any()]
    return out


def table(result: dict) -> list[str]:
    """The markdown rows docs/latency_models.md quotes."""
    lines = ["| SINR bin | fitting rows | held-out rows | KS D | p-value |", "|---|---|---|---|---|"]
    fit_rows = {b["sinr"]: b["fit_rows"] for b in result["bins"]}
    for k in result["ks"]["bins"] + [result["ks"]["overall"]]:
        rows = fit_rows.get(k["sinr"], sum(fit_rows.values()))
        lines.append(f"| {k['sinr']} | {rows} | {k['test_rows']} | {k['D']:.3f} | {k['p']:.2g} |")
    return lines


def splits() -> list[str]:
    """The overall KS of every leave-one-drive-out split (the shipped one is one of them)."""
    drives = FIT_DRIVES + (TEST_DRIVE,)
    lines = ["| held-out drive | KS D | p-value |", "|---|---|---|"]
    for held in sorted(drives):
        k = fit(tuple(d for d in drives if d != held), held)["ks"]["overall"]
        lines.append(f"| `{held}` | {k['D']:.3f} | {k['p']:.2g} |")
    return lines


def json_text(result: dict) -> str:
    return json.dumps(result, indent=1) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--write", action="store_true", help=f"write {SINR_FIT_FILE.name}")
    ap.add_argument("--splits", action="store_true", help="also every leave-one-drive-out split")
    ap.add_argument("--check", action="store_true", help="exit 1 unless the shipped file equals the fit")
    args = ap.parse_args(argv)
    result = fit()
    print(f"fit on {', '.join(FIT_DRIVES)}; held out {TEST_DRIVE}")
    print("\n".join(table(result)))
    if args.splits:
        print("\n".join(splits()))
    if args.write:
        write_text(SINR_FIT_FILE, json_text(result))
        print(f"wrote {SINR_FIT_FILE}")
    if args.check:
        same = SINR_FIT_FILE.is_file() and SINR_FIT_FILE.read_text() == json_text(result)
        print("shipped file equals the fit" if same else f"{SINR_FIT_FILE} differs from the fit")
        return 0 if same else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
