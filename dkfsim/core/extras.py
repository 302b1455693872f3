"""The one seam for optional heavy packages: imported only when a command needs them.

matplotlib (figures), Pillow (compact PNGs; ships with matplotlib),
dask.distributed (clusters), pyarrow (Parquet), pandas and xarray (notebook
conversions) are extras (``pip install 'dkfsim[plots]'``, ``[cluster]``,
``[notebook]``); numba (the compiled kernels, a core dependency) is imported
here too, on the first filter, so commands that never filter do not pay it, and so is
defusedxml (safe XML, a core dependency), when a SUMO FCD file is read.  Every other module imports them through these functions,
never at module level, so the core installs and imports without them and a
missing one is a clear error that says what to install.
"""

from __future__ import annotations

import importlib

from dkfsim.core.errors import DkfsimError

#: import name -> (what needs it, the pip command that installs it)
_HINTS = {
    "matplotlib": ("plotting", "pip install 'dkfsim[plots]' (or pip install matplotlib)"),
    "PIL": ("compact PNG figures", "pip install pillow"),
    "distributed": ("Dask clusters", "pip install 'dkfsim[cluster]' (or pip install distributed)"),
    "pyarrow": ("Parquet export", "pip install 'dkfsim[cluster]' (or pip install pyarrow), or export to .csv"),
    "pandas": ("to_frame()", "pip install 'dkfsim[notebook]' (or pip install pandas)"),
    "xarray": ("to_xarray()", "pip install 'dkfsim[notebook]' (or pip install xarray)"),
    "defusedxml": ("reading SUMO FCD files", "pip install defusedxml (a dependency of dkfsim: reinstall it)"),
    "numba": ("the compiled kernels", "pip install numba (or set DKFSIM_KERNELS=numpy)"),
}


def optional(name: str):
    """Import the optional module ``name`` (e.g. ``"pyarrow.parquet"``); a clear
    :class:`DkfsimError` naming the extra if it is missing."""
    try:
        return importlib.import_module(name)
    except ImportError:
        what, how = _HINTS.get(name.split(".")[0], ("this feature", f"pip install {name.split('.')[0]}"))
        raise DkfsimError(f"{what} needs the {name.split('.')[0]!r} package, which is not installed: "
                          f"{how}") from None


def available(name: str) -> bool:
    """True when the optional module ``name`` can be imported."""
    try:
        importlib.import_module(name)
        return True
    except ImportError:
        return False


def pyplot():
    """matplotlib's pyplot on the Agg backend (files only: works without a display)."""
    matplotlib = optional("matplotlib")
    matplotlib.use("Agg", force=True)
    return optional("matplotlib.pyplot")
