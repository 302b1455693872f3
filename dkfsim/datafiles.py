"""Data files a scenario names (measured latency traces, recorded tracks).

One place decides where a relative path points and how a column header is
matched, so the ``empirical`` latency model and the ``truth`` track agree.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

#: The repository root (the folder holding the ``dkfsim`` package).
REPO_ROOT = Path(__file__).resolve().parents[1]


def resolve_data_file(file: str, base_dir: str | os.PathLike | None = None) -> tuple[Path | None, list[Path]]:
    """The file a scenario names, and every place that was tried.

    Absolute paths are used as they are.  A relative path is looked up in
    ``base_dir`` (the scenario file's folder; the working directory when
    ``None``), then the repository root, then the repository's
    ``scenarios/`` folder (so a copy of a repository scenario made with
    ``to_dict``, e.g. for a Monte Carlo worker, still finds its data).
    """
    path = Path(os.path.expanduser(str(file)))
    if path.is_absolute():
        tried = [path]
    else:
        base = Path(base_dir) if base_dir is not None else Path.cwd()
        tried = [base / path, REPO_ROOT / path, REPO_ROOT / "scenarios" / path]
    for cand in tried:
        if cand.is_file():
            return cand.resolve(), tried
    return None, tried


def norm_name(name: str) -> str:
    """A column header reduced to lower-case letters and digits (``delay(ms)`` -> ``delayms``)."""
    return re.sub(r"[^0-9a-z]", "", str(name).lower())
