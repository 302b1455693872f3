"""``dkfsim plot``: figures from run and Monte Carlo folders."""

from __future__ import annotations

import argparse
from pathlib import Path

from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import clip
from dkfsim.report.plots import (DEFAULT_FORMATS, FORMATS, _check_formats, load_folder, plot_compare,
                                 plot_folder)

EPILOG = """\
examples:
  dkfsim plot out/case1                                   # out/case1/figures/{tracking,mse}.{png,pdf}
  dkfsim plot out/mc_case1 --format png                   # a Monte Carlo folder; adds nees.png
  dkfsim plot out/case1 out/case2 --compare --labels "case 1 (undirected)" "case 2 (directed)"
  dkfsim plot out/d0 out/d1 out/d2 out/d3 out/d4 --compare --component position \\
      --labels "d_t = 0" "d_t = 1" "d_t = 2" "d_t = 3" "d_t = 4" --out figs --name delay_bounds
"""


def add_command(sub) -> None:
    p = sub.add_parser(
        "plot", help="draw figures from run or Monte Carlo folders",
        description="Draw figures (matplotlib, Agg backend) from folders written by dkfsim run "
                    "(run.npz + summary.json) or dkfsim montecarlo (curves.npz + runs.csv + summary.json): "
                    "tracking (truth, fused, node 0, references), MSE per tick (log scale; Monte Carlo: "
                    "95% CI shaded) and, for Monte Carlo folders, NEES. With --compare, overlay the fused "
                    "MSE of several folders and the centralized filter of the first.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dirs", nargs="+", metavar="DIR", help="run or Monte Carlo folder(s)")
    p.add_argument("--out", metavar="FIGDIR",
                   help="folder for the figures (default: DIR/figures; with --compare: the first DIR's)")
    p.add_argument("--format", dest="formats", nargs="+", default=list(DEFAULT_FORMATS), choices=FORMATS,
                   metavar="FMT", help=f"file formats: {', '.join(FORMATS)} (default: png pdf)")
    p.add_argument("--compare", action="store_true",
                   help="overlay the fused MSE of all DIRs (same number of ticks) in one figure")
    p.add_argument("--relative", action="store_true",
                   help="with --compare: add a column with each MSE divided by the first folder's "
                        "centralized MSE (shows differences of a few per cent)")
    p.add_argument("--labels", nargs="+", metavar="LABEL", help="legend label per DIR (with --compare)")
    p.add_argument("--component", dest="components", nargs="+", metavar="NAME",
                   help="state components to draw, by name (position) or index (0); default: all")
    p.add_argument("--smooth", type=int, metavar="TICKS",
                   help="centred moving average of the MSE curves over TICKS ticks "
                        "(default: 2%% of the ticks for a single run, none for Monte Carlo)")
    p.add_argument("--name", default=None, metavar="STEM",
                   help="file name (without extension) of the --compare figure (default: compare_mse)")
    p.add_argument("--title", default=None,
                   help="title of the --compare figure (default: generated; a line saying what the curves are follows it)")
    p.set_defaults(func=cmd_plot)


def cmd_plot(args) -> int:
    formats = _check_formats(args.formats)
    if args.smooth is not None and args.smooth < 1:
        raise DkfsimError(f"--smooth: must be >= 1 tick, got {args.smooth}")
    if args.labels is not None and not args.compare:
        raise DkfsimError("--labels: only used with --compare")
    for flag in ("name", "title"):
        if getattr(args, flag) is not None and not args.compare:
            raise DkfsimError(f"--{flag}: only used with --compare")
    if args.relative and not args.compare:
        raise DkfsimError("--relative: only used with --compare")
    if args.compare and len(args.dirs) < 2:
        raise DkfsimError("--compare: give at least two folders")
    if args.name is not None and (not args.name.strip() or args.name != Path(args.name).name
                                  or args.name in (".", "..")):
        raise DkfsimError(f"--name {clip(args.name)}: a file name without folders (use --out for "
                          "the folder)")
    folders = [load_folder(d) for d in args.dirs]
    written = []
    if args.compare:
        out = Path(args.out) if args.out else folders[0].path / "figures"
        written = plot_compare(folders, out / (args.name or "compare_mse"), labels=args.labels,
                               formats=formats, components=args.components, smooth=args.smooth,
                               title=args.title, relative=args.relative)
    else:
        for f in folders:
            if args.out is None:
                out = f.path / "figures"
            elif len(folders) == 1:
                out = Path(args.out)
            else:
                out = Path(args.out) / f.path.resolve().name
            written += plot_folder(f, out, formats, args.components, args.smooth)
    for path in written:
        print(f"wrote {path}")
    return 0
