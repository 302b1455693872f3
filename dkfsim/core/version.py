"""The version of dkfsim (one place; the package and every output report it)."""

__version__ = "0.1.0"
