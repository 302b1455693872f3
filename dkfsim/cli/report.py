"""``dkfsim report``: one self-contained HTML page for a run, Monte Carlo or sweep folder."""

from __future__ import annotations

import argparse

from dkfsim.cli.common import say
from dkfsim.report.html_report import write_report

EPILOG = """\
examples:
  dkfsim report out/case1                       # -> out/case1/report.html
  dkfsim report out/mc                          # a Monte Carlo folder
  dkfsim report out/sweep_delay_bound.sqlite --out delay_report.html
"""


def configure(p) -> None:
    """``dkfsim report``'s arguments (its parser made by :func:`dkfsim.cli.main.build_parser`)."""
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = EPILOG
    p.description = ("Write a single HTML file (figures inline, no other files) for a folder written "
                     "by dkfsim run or dkfsim montecarlo, or for a sweep database (or a folder holding "
                     "one): the scenario, the network drawing (nodes, links, the graph the protocol "
                     "used; at most 60 nodes drawn), MSE and NEES tables, figures, packet and late "
                     "counts, versions and seeds. Open it in a browser or attach it to a lab note.")
    p.add_argument("dir", metavar="DIR", help="run or Monte Carlo folder, sweep database, or a folder "
                                              "holding one sweep database")
    p.add_argument("--out", metavar="FILE.html",
                   help="where to write the page (default: DIR/report.html; for a sweep database "
                        "<stem>.report.html beside it)")
    p.set_defaults(func=cmd_report)


def cmd_report(args) -> int:
    path = write_report(args.dir, args.out)
    say(f"wrote {path}")
    return 0
