"""``dkfsim plot``: figures from run and Monte Carlo folders."""

from __future__ import annotations

import argparse
import os
import re
from pathlib import Path

from dkfsim.cli.common import say
from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import clip
from dkfsim.experiments.sweep import is_database
from dkfsim.report.plots import (
    DEFAULT_FORMATS,
    FORMATS,
    check_formats,
    load_folder,
    plot_compare,
    plot_folder,
    relative_to,
)
from dkfsim.report.plots.style import PNG_DPI, png_resolution
from dkfsim.report.sweep.plot import plot_sweep

EPILOG = """\
examples:
  dkfsim plot out/case1                                   # out/case1/figures/{tracking,mse}.{png,pdf}
  dkfsim plot out/mc_case1 --format png                   # a Monte Carlo folder; adds nees.png
  dkfsim plot out/case1 out/case2 --compare --labels "case 1 (undirected)" "case 2 (directed)"
  dkfsim plot out/crossing --at 1 100 200                 # a run with mobility:: network_over_time at 3 ticks
  dkfsim plot out/sweep_delay_bound.sqlite --x links.default.latency.d_t --hue protocol
  dkfsim plot out/delay.csv --x links.default.latency.d_t --metric anees --where protocol=tree
  dkfsim plot out/d0 out/d1 out/d2 out/d3 out/d4 --compare --component position \\
      --labels "d_t = 0" "d_t = 1" "d_t = 2" "d_t = 3" "d_t = 4" --out figs --name delay_bounds
"""


def configure(p) -> None:
    """``dkfsim plot``'s arguments (its parser made by :func:`dkfsim.cli.main.build_parser`)."""
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = EPILOG
    p.description = ("Draw figures (matplotlib, Agg backend) from folders written by dkfsim run "
                     "(run.npz + summary.json) or dkfsim montecarlo (curves.npz + runs.csv + summary.json): "
                     "tracking (truth, fused, node 0, references), MSE per tick (log scale; Monte Carlo: "
                     "95% CI shaded), for Monte Carlo folders NEES, and for a run with mobility: "
                     "network_over_time and topology_errors. With --compare, overlay the fused "
                     "MSE of several folders and the centralized filter of the first. Given a sweep database "
                     "(or its --export .csv/.parquet), draw a metric against one grid key (--x) with "
                     "95% interval bands over the runs, one line per estimate or per value of --hue.")
    p.add_argument("dirs", nargs="+", metavar="DIR",
                   help="run or Monte Carlo folder(s), or one sweep database / export file")
    p.add_argument("--out", metavar="FIGDIR",
                   help="folder for the figures (default: DIR/figures; with --compare: the first DIR's)")
    p.add_argument("--format", dest="formats", nargs="+", default=list(DEFAULT_FORMATS), choices=FORMATS,
                   metavar="FMT", help=f"file formats: {', '.join(FORMATS)} (default: png pdf)")
    p.add_argument("--dpi", type=int, default=None, metavar="N",
                   help=f"resolution of the PNG files (default: {PNG_DPI[0]}, for screens and slides; "
                        "300 for print: the PDF beside each is the vector figure)")
    p.add_argument("--compare", action="store_true",
                   help="overlay the fused MSE of all DIRs (same number of ticks) in one figure")
    p.add_argument("--relative", action="store_true",
                   help="with --compare: add a column with each MSE divided by the first folder's "
                        "centralized MSE (shows differences of a few per cent)")
    p.add_argument("--relative-to", dest="relative_to", metavar="NAME",
                   help="paired comparison with a reference, run by run on the same draws: a Monte "
                        "Carlo folder's paired figure against estimate NAME (default: the one its "
                        "summary.json names); a sweep drawn as the ratio to estimate NAME, or with "
                        "--hue to the hue key's value NAME")
    p.add_argument("--labels", nargs="+", metavar="LABEL", help="legend label per DIR (with --compare)")
    p.add_argument("--component", dest="components", nargs="+", metavar="NAME",
                   help="state components to draw, by name (position) or index (0); default: all")
    p.add_argument("--smooth", type=int, metavar="TICKS",
                   help="centred moving average of the MSE curves over TICKS ticks "
                        "(default: 2%% of the ticks for a single run, none for Monte Carlo)")
    p.add_argument("--at", nargs="+", type=int, metavar="TICK",
                   help="a run with mobility: the ticks (1..K) drawn in network_over_time "
                        "(default: six evenly spaced)")
    p.add_argument("--name", default=None, metavar="STEM",
                   help="file name (without extension) of the --compare figure (default: compare_mse)")
    p.add_argument("--title", default=None,
                   help="title of the --compare figure (default: generated; a line saying what the curves are follows it)")
    s = p.add_argument_group("sweeps (SWEEP: a sweep database or its .csv/.parquet export)")
    s.add_argument("--x", metavar="KEY", help="grid key on the x axis (default: the only one)")
    s.add_argument("--hue", metavar="KEY",
                   help="one line per value of this grid key (for one --estimate); default: one "
                        "line per estimate")
    s.add_argument("--metric", default="mse", metavar="NAME",
                   help="column to draw: mse (default; one panel per component), anees, "
                        "messages_per_tick, bytes_per_tick, disagreement, lost, late")
    s.add_argument("--estimate", metavar="NAME",
                   help="with --hue: the estimate drawn (default fused); without: a comma-separated "
                        "list of estimates to draw (default: all)")
    s.add_argument("--where", nargs="+", metavar="KEY=VALUE", default=[],
                   help="fix grid keys that are neither --x nor --hue")
    s.add_argument("--xlabel", metavar="TEXT",
                   help="x axis label (default: what the --x key is, with its unit, e.g. "
                        "'per-hop delay bound d_t [ticks]')")
    p.set_defaults(func=cmd_plot)


SWEEP_FLAGS = ("x", "hue", "estimate", "xlabel")


def _is_sweep(path: str) -> bool:
    p = Path(path)
    return p.is_file() and (is_database(p) or p.suffix.lower() in (".csv", ".parquet", ".pq"))


def cmd_plot_sweep(args, formats) -> int:
    for flag in ("compare", "relative"):
        if getattr(args, flag):
            raise DkfsimError(f"--{flag}: only for run and Monte Carlo folders, not a sweep")
    for flag in ("labels", "smooth", "at"):
        if getattr(args, flag) is not None:
            raise DkfsimError(f"--{flag}: only for run and Monte Carlo folders; a sweep takes --x, "
                              "--hue, --metric, --estimate, --where, --component, --xlabel")
    path = Path(args.dirs[0])
    curves_x = (args.x or "x").removeprefix("param:").replace(".", "_")
    stem = args.name or f"{args.metric}_vs_{curves_x}" + (f"_by_{args.hue.replace('.', '_')}"
                                                         if args.hue else "") + \
        (f"_relative_to_{re.sub(r'[^A-Za-z0-9_.-]', '_', args.relative_to)}" if args.relative_to else "")
    out = Path(args.out) if args.out else _default_out(path.parent, path.stem + "_figures")
    written = plot_sweep(path, out / stem, x=args.x, hue=args.hue, metric=args.metric,
                         estimate=args.estimate, where=args.where, formats=formats, title=args.title,
                         relative_to=args.relative_to, components=args.components, xlabel=args.xlabel)
    for f in written:
        say(f"wrote {f}")
    return 0


#: Longest ``--name`` (bytes): the figure file name, its extension and the temporary suffix must
#: fit the 255 bytes a file name may have.
MAX_NAME_BYTES = 200


def _check_name(name: str | None) -> None:
    """``--name`` is a file name: no folder part, not absolute, not too long (for every kind of DIR)."""
    if name is None:
        return
    if not name.strip() or name != Path(name).name or name in (".", "..") or "\0" in name:
        raise DkfsimError(f"--name {clip(name)}: a file name without folders (use --out for the folder)")
    if len(os.fsencode(name)) > MAX_NAME_BYTES:
        raise DkfsimError(f"--name: {len(os.fsencode(name))} bytes, more than the {MAX_NAME_BYTES} a "
                          "figure's file name may have")


def _default_out(folder: Path, name: str) -> Path:
    """``folder/name`` where figures go by default; refused when it is a symbolic link (a folder
    someone sent could point it anywhere: dkfsim never writes through it)."""
    out = folder / name
    if out.is_symlink():
        raise DkfsimError(f"{out}: is a symbolic link (to {clip(os.readlink(out))}); dkfsim plot does "
                          "not write figures through a link in a folder it reads: remove it, or give "
                          "--out FIGDIR")
    return out


def cmd_plot(args) -> int:
    if args.dpi is None:                 # the resolution in force (PNG_DPI: 150 unless a caller chose)
        return _cmd_plot(args)
    if not 30 <= args.dpi <= 1200:
        raise DkfsimError(f"--dpi: a resolution from 30 to 1200, got {args.dpi}")
    with png_resolution(args.dpi):
        return _cmd_plot(args)


def _cmd_plot(args) -> int:
    formats = check_formats(args.formats)
    _check_name(args.name)
    if len(args.dirs) == 1 and _is_sweep(args.dirs[0]):
        return cmd_plot_sweep(args, formats)
    for flag in SWEEP_FLAGS + ("metric",):
        value = getattr(args, flag)
        if value is not None and not (flag == "metric" and value == "mse"):
            raise DkfsimError(f"--{flag}: only for a sweep database or export (give one file)")
    if args.where:
        raise DkfsimError("--where: only for a sweep database or export (give one file)")
    if args.smooth is not None and args.smooth < 1:
        raise DkfsimError(f"--smooth: must be >= 1 tick, got {args.smooth}")
    if args.labels is not None and not args.compare:
        raise DkfsimError("--labels: only used with --compare")
    for flag in ("name", "title"):
        if getattr(args, flag) is not None and not args.compare:
            raise DkfsimError(f"--{flag}: only used with --compare")
    if args.at is not None and args.compare:
        raise DkfsimError("--at: not with --compare (it picks the ticks of one run's network_over_time)")
    if args.relative and not args.compare:
        raise DkfsimError("--relative: only used with --compare")
    if args.compare and len(args.dirs) < 2:
        raise DkfsimError("--compare: give at least two folders")
    folders = [load_folder(d) for d in args.dirs]
    if args.relative_to is not None:
        if args.compare:
            raise DkfsimError("--relative-to: not with --compare (use --relative there)")
        folders = [relative_to(f, args.relative_to) for f in folders]
    written = []
    if args.compare:
        out = Path(args.out) if args.out else _default_out(folders[0].path, "figures")
        written = plot_compare(folders, out / (args.name or "compare_mse"), labels=args.labels,
                               formats=formats, components=args.components, smooth=args.smooth,
                               title=args.title, relative=args.relative)
    else:
        for f in folders:
            if args.out is None:
                out = _default_out(f.path, "figures")
            elif len(folders) == 1:
                out = Path(args.out)
            else:
                out = Path(args.out) / f.path.resolve().name
            written += plot_folder(f, out, formats, args.components, args.smooth, args.at)
    for path in written:
        say(f"wrote {path}")
    return 0
