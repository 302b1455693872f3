"""What every sub-command shares: the scenario arguments, ``--yes``, loading."""

from __future__ import annotations

import argparse

from dkfsim.config.load import load_scenario


def add_scenario_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", metavar="FILE", help="scenario YAML file (see README: 'Scenario files')")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario key by its dotted path, value parsed as YAML; "
                        "repeatable (e.g. --set links.default.latency.d_t=2 --set protocol=flood)")


def add_yes_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--yes", action="store_true",
                   help="run even when the estimated time is above 10 minutes (the estimate is "
                        "printed and the command stops without it); work that cannot fit in memory "
                        "is refused either way")


def load_from_args(args):
    """The scenario of ``args.scenario`` with ``--set``, ``--seed`` and ``--steps`` applied."""
    overrides = list(args.overrides)
    for key in ("seed", "steps"):
        val = getattr(args, key, None)
        if val is not None:
            overrides.append(f"{key}={val}")
    return load_scenario(args.scenario, overrides=overrides)
