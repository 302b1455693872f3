"""Progress bars for the Python API: ``progress=True`` draws a ``tqdm.auto`` bar.

``tqdm.auto`` is a widget in a Jupyter notebook and a text bar in a terminal,
so ``dkfsim.run(..., progress=True)``, ``dkfsim.montecarlo(..., progress=True)``
and sweeps show progress wherever they are called from.  A callable is used as
given (``progress(done, total)``), ``None`` / ``False`` show nothing.  The CLI
keeps its own bars on stderr (shown only on a terminal).
"""

from __future__ import annotations

import contextlib

from tqdm.auto import tqdm

from dkfsim.core.files import printable


@contextlib.contextmanager
def progress_callback(progress, total: int, desc: str, unit: str):
    """Yield a ``callback(done, total)`` (or None) for ``progress`` (True, a callable, None)."""
    if progress is None or progress is False:
        yield None
        return
    if callable(progress):
        yield progress
        return
    bar = tqdm(total=total, desc=printable(desc), unit=unit, leave=False)
    try:
        yield lambda done, _total: bar.update(done - bar.n)
    finally:
        bar.close()
