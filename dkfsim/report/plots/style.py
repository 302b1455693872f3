"""What every figure shares: estimate labels and colours, smoothing, axes, atomic saving.

See :mod:`dkfsim.report.plots`.
"""

from __future__ import annotations

import contextlib
import io
import math
from pathlib import Path

import numpy as np

from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import available, optional, pyplot
from dkfsim.core.files import printable, shown
from dkfsim.core.folders import WriteFailed, replacing
from dkfsim.core.params import suggest
from dkfsim.report.plots.folders import Folder

FORMATS = ("png", "pdf", "svg")
DEFAULT_FORMATS = ("png", "pdf")

#: Display order, legend label and fixed colour of the built-in estimate names: ``fused``,
#: ``local`` and the default name of every built-in estimator kind (design §8).  A built-in
#: name keeps its colour in every figure (run, Monte Carlo, sweep, report, notebook).
ESTIMATES: dict[str, tuple[str, str]] = {
    "fused": ("fused: anti-delay DKF", "C0"),
    "local": ("local: DKF node estimates (mean over nodes)", "C9"),
    "centralized": ("centralized: all data on time", "k"),
    "centralized_delayed": ("centralized_delayed: over delayed direct links", "C2"),
    "fusion_centre": ("fusion_centre: the DKF's fusion at one node, over the network", "#000080"),
    "no_buffer": ("no_buffer: L = 1, fused", "C1"),
    "ci_consensus": ("ci_consensus: consensus on information", "C3"),
    "local_only": ("local_only: own sensor", "C7"),
    "kcf": ("kcf: Kalman-consensus filter", "C4"),
    "icf": ("icf: information-weighted consensus", "C5"),
    "diffusion_kf": ("diffusion_kf: diffusion Kalman filter", "C6"),
    "hcmci": ("hcmci: hybrid consensus (measurements + information)", "C8"),
    "anti_delay_dkf": ("anti_delay_dkf: a second anti-delay DKF, fused", "#393b79"),
}

#: Colours for every other name (a plugin's estimator, a second DKF under its own name):
#: none is within 0.18 (RGB distance) of a colour above or of another one here, so an
#: unknown name is never drawn like a built-in.  They go to the unknown names of one result
#: in sorted name order (:func:`color_of`), so a name's colour does not depend on where it
#: comes in a figure; beyond ten unknown names they repeat.
OTHER_COLORS = ("#e7298a", "#1b9e77", "#a6761d", "#637939", "#7b4173",
                "#e6ab02", "#5254a3", "#d6616b", "#66a61e", "#9c9ede")


#: Longest name drawn in a figure (longer ones are cut with "…").
LABEL_LIMIT = 120


def plain(text, limit: int = LABEL_LIMIT) -> str:
    """A name read from a file or given on the command line (an estimate, a component, a
    sensor, a grid value, ``--labels``, ``--title``) as matplotlib must draw it: plain text.
    Control characters go through the one escaper (:func:`dkfsim.core.files.printable`: drawn
    as ``\\x1b``, so no font lacks their glyph and no warning carries them raw to a
    terminal), every ``$`` is escaped, so ``$\\nosuch$`` is not parsed as mathtext (a
    ParseException), and the text is cut at ``limit`` characters."""
    s = printable(text)
    if len(s) > limit:
        s = s[:limit - 1] + "…"
    return s.replace("$", "\\$")


def label_of(name: str) -> str:
    """The legend label of an estimate: its description when known, else its name (plain)."""
    known = ESTIMATES.get(name)
    return known[0] if known is not None else plain(name)


def color_of(name: str, names=()) -> str:
    """The colour of estimate ``name`` in a figure of a result whose estimates are ``names``
    (all of the result's names, not only those drawn, so that choosing fewer changes no colour).
    A built-in name has its fixed colour; any other takes :data:`OTHER_COLORS` by its rank
    among the result's other names in sorted order (``name`` counts as one of them)."""
    known = ESTIMATES.get(name)
    if known is not None:
        return known[1]
    others = sorted({str(a) for a in names if a not in ESTIMATES} | {name})
    return OTHER_COLORS[others.index(name) % len(OTHER_COLORS)]


def estimate_order(names) -> list[str]:
    known = [a for a in ESTIMATES if a in names]
    return known + sorted(a for a in names if a not in ESTIMATES)


# ----------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------

def moving_average(a: np.ndarray, w: int) -> np.ndarray:
    """Centred moving average over ``w`` rows along axis 0; the window shrinks at the ends."""
    a = np.asarray(a, dtype=float)
    if w <= 1:
        return a
    K = a.shape[0]
    c = np.concatenate([np.zeros((1,) + a.shape[1:]), np.cumsum(a, axis=0)])
    lo = np.clip(np.arange(K) - w // 2, 0, K)
    hi = np.clip(np.arange(K) - w // 2 + w, 0, K)
    n = (hi - lo).reshape((K,) + (1,) * (a.ndim - 1))
    return (c[hi] - c[lo]) / n


def default_smooth(folder: Folder) -> int:
    """Single runs: 2 % of the ticks (the squared error of one run is very noisy); Monte Carlo: none."""
    return max(1, folder.K // 50) if folder.kind == "run" else 1


def select_components(have, wanted, of) -> list[int]:
    """``--component``: indices into ``have`` (the components of ``of``, a run folder or "the
    sweep") of the components named (or numbered) in ``wanted``, in the order given; all when
    empty.  A name that is neither is refused with the closest one."""
    have = [str(c) for c in have]
    if not wanted:
        return list(range(len(have)))
    out = []
    for s in map(str, wanted):
        if s in have:
            out.append(have.index(s))
        elif s.isdigit() and int(s) < len(have):
            out.append(int(s))
        else:
            raise DkfsimError(f"--component: {s!r} is not a component of {of}{suggest(s, have)} "
                              f"(components: {', '.join(have)}, or 0..{len(have) - 1})")
    return out


def unit_label(unit: str, squared: bool = False) -> str:
    if not unit:
        return ""
    if squared:
        return f" [({unit})$^2$]" if "/" in unit or "$" in unit else f" [{unit}$^2$]"
    return f" [{unit}]"


def mse_ylabel(folder: Folder, i: int) -> str:
    comp, unit = folder.components[i], folder.units[i]
    return f"{plain(comp)} MSE{unit_label(unit, squared=True)}"


def mse_note(folder: Folder, smooth: int) -> str:
    if folder.kind == "montecarlo":
        note = f"mean over {folder.n_runs} Monte Carlo runs" if folder.n_runs else "mean over Monte Carlo runs"
        if folder.ci:
            note += ", 95 % CI shaded"
    else:
        note = "single run: squared error"
    if smooth > 1:
        note += f", {smooth}-tick moving average"
    return note


#: Resolution of PNG figures: for screens and slides (the PDF beside each is the vector figure for
#: print); :func:`png_resolution` lowers it for the inline figures of a report.  At 300 dpi and 256
#: colours a Monte Carlo's MSE figure took 0.76 MB (issue 34 §6).
PNG_DPI = [150]
#: Colours of a PNG's palette: enough for the curves, bands and text of these figures.
PNG_COLOURS = 64


@contextlib.contextmanager
def png_resolution(dpi: int):
    """PNGs written inside the block use ``dpi`` (e.g. inline figures of an HTML report)."""
    PNG_DPI.append(int(dpi))
    try:
        yield
    finally:
        PNG_DPI.pop()


def _save_png(fig, fh, dpi: int | None = None) -> None:
    """PNG with a :data:`PNG_COLOURS`-colour palette, into the binary file ``fh``: a fraction of
    the size of matplotlib's RGBA, the same look."""
    dpi = PNG_DPI[-1] if dpi is None else dpi
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    if available("PIL"):
        Image = optional("PIL.Image")
        img = Image.open(buf).convert("RGB").quantize(colors=PNG_COLOURS, method=Image.Quantize.MEDIANCUT)
        img.save(fh, format="PNG", optimize=True, dpi=(dpi, dpi))   # the resolution, for layout programs
    else:                 # Pillow ships with matplotlib; keep the plain file if it is missing
        fh.write(buf.getvalue())


def save_figure(fig, stem: Path, formats) -> list[Path]:
    """Write ``fig`` as ``stem.<fmt>`` for each format, each file atomically; a folder made
    here for them is removed again when nothing could be written into it (a full disk)."""
    stem = Path(stem)
    made = None
    try:
        if not stem.parent.exists():
            made = stem.parent
        stem.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DkfsimError(f"{shown(stem.parent)}: cannot create the figure folder ({exc.strerror})") from None
    out = []
    try:
        for fmt in formats:
            path = stem.with_name(f"{stem.name}.{fmt}")
            try:                       # written beside (a new file, never through a link), then renamed
                with replacing(path, "wb") as fh:
                    if fmt == "png":
                        _save_png(fig, fh)
                    else:
                        fig.savefig(fh, bbox_inches="tight", format=fmt)
            except WriteFailed as exc:
                raise DkfsimError(f"{shown(path)}: cannot write the figure ({exc.strerror})") from None
            out.append(path)
    except BaseException:
        if made is not None:
            with contextlib.suppress(OSError):
                made.rmdir()                 # (only if still empty)
        raise
    finally:
        fig.clf()
        pyplot().close(fig)
    return out


def draw_averages(ax, entries, folder: Folder) -> None:
    """A column right of the panel: each curve's time-averaged MSE after the burn-in, in its colour
    and named (``entries``: ``("name: value", colour)``; colour alone identifies nothing for a
    reader who cannot tell the hues apart), with the 95 % interval over runs when known."""
    b = folder.burn_rows()
    pm = any("±" in text for text, _ in entries)
    head = f"MSE, mean\nover t ≥ {folder.t[min(b, folder.K - 1)]:g} s" + ("\n(± 95 % half-width)" if pm else "")
    ax.text(1.02, 1.0, head + ":", transform=ax.transAxes, ha="left", va="top", fontsize=7.5, color="0.3")
    top = 0.80 - (0.09 if pm else 0.0)
    step = min(0.105, top / max(1, len(entries)))
    for j, (text, col) in enumerate(entries):
        ax.text(1.02, top - step * j, text, transform=ax.transAxes, ha="left", va="top",
                fontsize=7.5, color=col, fontweight="bold")


def average_text(folder: Folder, estimate: str, i: int) -> str:
    m = folder.time_average(estimate, i)
    ci = folder.ci95(estimate, i)
    return f"{m:.4g}" if ci is None else f"{m:.4g} ± {(ci[1] - ci[0]) / 2:.2g}"


def legend_below(fig, ax, ncol=2, fontsize=8.5, title=None):
    """One legend for all panels, under them, so that it never hides a curve.  ``ax``: the
    panel whose entries it lists, or a list of panels (their entries one after the other);
    ``title``: a line above the entries (what line styles or colours mean)."""
    handles, labels = [], []
    for a in (ax if isinstance(ax, (list, tuple)) else [ax]):
        h, lab = a.get_legend_handles_labels()
        handles += h
        labels += lab
    fig.tight_layout()
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=ncol,
               fontsize=fontsize, frameon=False, title=title, title_fontsize=fontsize)


def check_formats(formats) -> tuple[str, ...]:
    formats = tuple(formats)
    if not formats:
        raise DkfsimError("--format: give at least one format")
    for f in formats:
        if f not in FORMATS:
            raise DkfsimError(f"--format: unknown format {f!r}; choose from {', '.join(FORMATS)}")
    return formats


def positive_only(a):
    """Zeros (exact estimates) cannot be drawn on a log axis; mask them."""
    a = np.asarray(a, dtype=float)
    return np.where(a > 0, a, np.nan)


def log_band(lo, hi, mean):
    """A confidence band for a log axis.  Where the lower bound is <= 0 (a t-interval of few
    runs) a log axis cannot show it: the band starts at the mean there (open below) instead
    of running down to the axis' floor as if values near 0 were drawn (docs/decisions.md, 200);
    :data:`OPEN_BELOW` is the caption saying so (give it when :func:`opens_below`)."""
    lo, mean = np.asarray(lo, dtype=float), np.asarray(mean, dtype=float)
    return np.where(lo > 0, lo, mean), positive_only(hi)


#: What a figure's caption adds when a band is open below (:func:`log_band`).
OPEN_BELOW = "band drawn from the mean up where its lower end is <= 0 (not on a log axis)"


def opens_below(lo) -> bool:
    """True when some lower bound of a band is <= 0 (so :func:`log_band` opens it below)."""
    lo = np.asarray(lo, dtype=float)
    return bool(np.any(np.isfinite(lo) & (lo <= 0)))


#: Labelled ticks of a log axis by the decades it spans: up to 2, at 1, 2 and 5 times each power
#: of ten; up to 4, at 1 and 3 times; beyond, at the powers of ten (enough to read it by then).
LOG_SUBS = ((2.0, (1.0, 2.0, 5.0)), (4.0, (1.0, 3.0)), (math.inf, (1.0,)))


def plain_log_ticks(ax, axis: str = "y") -> None:
    """Labelled ticks on a log axis: 0.2, 0.5, 1, 2, 5 ... over a few decades (matplotlib
    labels only 1 and 10 there), fewer over more (:data:`LOG_SUBS`); labels as plain numbers
    (0.05, 1e-05) instead of 5 x 10^-2.  The ticks follow the limits set later."""
    ticker = optional("matplotlib.ticker")

    class Ticks(ticker.LogLocator):  # type: ignore[name-defined]   # matplotlib, imported when drawing
        def tick_values(self, vmin, vmax):
            lo, hi = sorted((max(vmin, 1e-300), max(vmax, 1e-300)))
            decades = np.log10(hi / lo)
            subs = next(s for top, s in LOG_SUBS if decades <= top)
            self.set_params(subs=subs, numticks=15)
            return super().tick_values(vmin, vmax)

    which = ax.yaxis if axis == "y" else ax.xaxis
    which.set_major_locator(Ticks(base=10.0))
    which.set_major_formatter(ticker.FuncFormatter(lambda v, _pos=None: f"{v:g}"))
    which.set_minor_formatter(ticker.NullFormatter())


def log_limits(ax, curves) -> None:
    """Fit the log axis to the mean curves (not to the bands, whose lower ends can be ~0)."""
    plain_log_ticks(ax)
    vals = np.concatenate([np.asarray(c, dtype=float).ravel() for c in curves])
    vals = vals[np.isfinite(vals) & (vals > 0)]
    if vals.size:
        ax.set_ylim(np.percentile(vals, 0.5) / 2.0, vals.max() * 2.0)

