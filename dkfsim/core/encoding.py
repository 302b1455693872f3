"""One encoding of numbers in every JSON and CSV file dkfsim writes.

Non-finite floats are the strings ``"nan"``, ``"inf"`` and ``"-inf"`` (the
spelling of Python's ``repr``, which ``float()``, numpy and pandas read
back); :func:`from_json` turns them back into floats.  ``null`` in JSON (an
empty CSV cell) means "not applicable", never NaN.  numpy scalars become
Python numbers.
"""

from __future__ import annotations

import json
import math

import numpy as np

NONFINITE = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}


def number_text(v: float) -> str | float:
    """A float for JSON: itself when finite, else ``"nan"``, ``"inf"`` or ``"-inf"``."""
    return v if math.isfinite(v) else repr(float(v))


def to_json(obj):
    """A copy of ``obj`` that standard JSON can hold (see the module docstring)."""
    if isinstance(obj, dict):
        return {str(k): to_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set)):
        return [to_json(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_json(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return number_text(float(obj))
    if obj is None or isinstance(obj, (str, int)):
        return obj
    return str(obj)


def from_json(obj):
    """``obj`` with the strings ``"nan"``, ``"inf"``, ``"-inf"`` read back as floats."""
    if isinstance(obj, dict):
        return {k: from_json(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [from_json(v) for v in obj]
    if isinstance(obj, str) and obj in NONFINITE:
        return NONFINITE[obj]
    return obj


def csv_cell(v):
    """A CSV cell: floats by ``repr`` (``nan``, ``inf`` included), ``None`` empty."""
    if v is None:
        return ""
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, (list, dict)):
        return json.dumps(to_json(v), sort_keys=True, separators=(",", ":"))
    return v
