"""Writing result folders: the folder itself and strict JSON.

Every command that writes results (``run``, ``montecarlo``, ``maxdelay``)
creates its folder and writes its JSON here, so the error for an unwritable
folder and the JSON dialect (standard JSON: NaN -> null, infinities ->
``"inf"`` / ``"-inf"``, numpy -> Python) are the same everywhere.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .errors import DkfsimError


def output_folder(out_dir) -> Path:
    """Create ``out_dir`` (and parents); a clear error if that is impossible."""
    if not str(out_dir).strip():
        raise DkfsimError("--out: empty path; give the folder to write into")
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DkfsimError(f"--out {out_dir}: cannot create the output folder ({exc.strerror})") from None
    return out


def to_json(obj):
    """A copy of ``obj`` that standard JSON can hold."""
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
        v = float(obj)
        if math.isnan(v):
            return None
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return v
    if obj is None or isinstance(obj, (str, int)):
        return obj
    return str(obj)


def write_json(path, obj) -> None:
    """Write ``obj`` as standard JSON; converted first, so a failure leaves no half file."""
    text = json.dumps(to_json(obj), indent=2, allow_nan=False) + "\n"
    with open(path, "w") as fh:
        fh.write(text)
