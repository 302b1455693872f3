"""Results as pandas and xarray objects, for notebooks (the ``notebook`` extra).

:func:`rows_frame` turns tidy rows (``run, seed, estimate, component`` + the
metrics: docs/design.md §8) into a :class:`pandas.DataFrame` with the same
columns, in the same order, as the files (``rows.csv``, ``runs.csv``, a sweep
export), so a notebook and a file reader see one table.  :func:`run_dataset`
gives a run's arrays as an :class:`xarray.Dataset` with named dimensions
(``tick``, ``node``, ``state``, ...) and :func:`curves_dataset` the pooled
Monte Carlo curves.  pandas and xarray are optional: imported through
:mod:`dkfsim.core.extras`, a missing one is a clear error naming the extra.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from dkfsim.core.extras import optional


def rows_frame(rows: Sequence, columns: Sequence[str]):
    """A DataFrame of tidy rows with exactly ``columns``, in order.

    ``rows`` are mappings (a missing key is NaN) or sequences in column order;
    ``None`` (SQLite's NULL, "not applicable") becomes NaN in metric columns.
    """
    pd = optional("pandas")
    columns = list(columns)
    if rows and isinstance(rows[0], Mapping):
        data = [[row.get(c) for c in columns] for row in rows]
    else:
        data = [list(row) for row in rows]
    frame = pd.DataFrame(data, columns=columns)
    for c in columns:
        if c not in ("estimate", "component", "param_hash") and frame[c].dtype == object:
            converted = pd.to_numeric(frame[c], errors="coerce")
            if converted.notna().sum() == frame[c].notna().sum():   # numbers and None only
                frame[c] = converted
    return frame


def _dims(key: str, shape: tuple, K: int, n: int, nx: int) -> tuple[str, ...] | None:
    """Dimension names of a ``run.npz`` array (docs/design.md §8), None when unknown."""
    if key == "t":
        return ("tick",)
    if key in ("truth", "x_final") or key.startswith("x_"):
        if shape == (K, nx):
            return ("tick", "state")
        if shape == (K, n, nx):
            return ("tick", "node", "state")
    if key.startswith("P_"):
        if shape == (K, nx, nx):
            return ("tick", "state", "state_j")
        if shape == (K, n, nx, nx):
            return ("tick", "node", "state", "state_j")
    if key in ("Phi", "Q", "P0") and shape == (nx, nx):
        return ("state", "state_j")
    if key == "x0_mean" and shape == (nx,):
        return ("state",)
    if key == "arrival" and shape == (n, n, K):
        return ("node", "origin", "tick")
    if key == "weights_A" and shape == (n, n):
        return ("node", "origin")
    if key == "crashed" and shape == (n, K):
        return ("node", "tick")
    return None


def run_dataset(arrays: Mapping, components: Sequence[str], n: int, attrs: Mapping | None = None):
    """A run's arrays as an :class:`xarray.Dataset`.

    Dimensions ``tick`` (coordinate ``time`` in seconds), ``node``, ``state``
    (coordinate: the component names), ``state_j`` (the second index of a
    covariance), ``origin`` (``arrival``, ``weights_A``).  The sensors' ``H_i``,
    ``R_i``, ``y_i`` are stacked into ``H``, ``R``, ``y`` on (``sensor``, ``meas``)
    when every sensor measures the same number of values (else they stay in the
    RunResult only); scalars (``buffer_length``) become attributes.
    """
    xr = optional("xarray")
    truth = np.asarray(arrays["truth"])
    K, nx = truth.shape
    comps = list(components)
    data_vars, out_attrs = {}, dict(attrs or {})
    for key, value in arrays.items():
        a = np.asarray(value)
        if key == "t":
            continue
        if a.ndim == 0:
            out_attrs[key] = a.item()
            continue
        dims = _dims(key, a.shape, K, n, nx)
        if dims is not None:
            data_vars[key] = (dims, a)
    data_vars.update(_sensor_vars(arrays, n))
    coords = {"tick": np.arange(K), "time": ("tick", np.asarray(arrays["t"], dtype=float)),
              "state": comps, "state_j": comps, "node": np.arange(n)}
    for dim in ("origin", "sensor"):
        if any(dim in d for d, _ in data_vars.values()):
            coords[dim] = np.arange(n)
    return xr.Dataset(data_vars, coords=coords, attrs=out_attrs)


def _sensor_vars(arrays: Mapping, n: int) -> dict:
    """``H``, ``R``, ``y`` stacked over the sensors when their measurement sizes agree."""
    if not all(f"{k}_{i}" in arrays for k in ("H", "R", "y") for i in range(n)):
        return {}
    H = [np.asarray(arrays[f"H_{i}"]) for i in range(n)]
    if len({h.shape for h in H}) != 1:
        return {}
    return {"H": (("sensor", "meas", "state"), np.stack(H)),
            "R": (("sensor", "meas", "meas_j"), np.stack([np.asarray(arrays[f"R_{i}"]) for i in range(n)])),
            "y": (("tick", "sensor", "meas"), np.stack([np.asarray(arrays[f"y_{i}"]) for i in range(n)],
                                                       axis=1))}


def curves_dataset(t, estimates, components, curves: Mapping, attrs: Mapping | None = None):
    """Pooled Monte Carlo curves as an :class:`xarray.Dataset`: each ``(A, K, nx)`` array
    on (``estimate``, ``tick``, ``state``), each ``(A, K)`` one on (``estimate``, ``tick``)."""
    xr = optional("xarray")
    names, comps = list(estimates), list(components)
    A, K = len(names), len(t)
    data_vars: dict[str, tuple[tuple[str, ...], np.ndarray]] = {}
    for key, value in curves.items():
        a = np.asarray(value)
        if a.shape == (A, K, len(comps)):
            data_vars[key] = (("estimate", "tick", "state"), a)
        elif a.shape == (A, K):
            data_vars[key] = (("estimate", "tick"), a)
    coords = {"estimate": names, "tick": np.arange(K), "time": ("tick", np.asarray(t, dtype=float)),
              "state": comps}
    return xr.Dataset(data_vars, coords=coords, attrs=dict(attrs or {}))
