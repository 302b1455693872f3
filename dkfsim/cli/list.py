"""``dkfsim list [what]``: every registered component, its description and parameters."""

from __future__ import annotations

from pydantic_core import PydanticUndefined

from dkfsim.cli.common import say
from dkfsim.core.datafiles import datasets
from dkfsim.core.registry import REGISTRIES, load_plugin

#: Keys a parameter model has for the registry itself, not as a parameter.
_NOT_PARAMS = {"model", "kind"}


def configure(p) -> None:
    """``dkfsim list``'s arguments (its parser made by :func:`dkfsim.cli.main.build_parser`)."""
    p.description = ("List what a scenario can name: estimators, latency models, protocols, media, "
                     "graph generators, sensor kinds, metrics, trajectory kinds and the shipped datasets, "
                     "each with a one-line description and its parameters (defaults in brackets). "
                     "Installed plugins are included; a plugin file (a scenario's plugins: entry) with "
                     "--plugin.")
    p.add_argument("what", nargs="?", choices=list(REGISTRIES) + ["datasets"],
                   help="one family (default: all)")
    p.add_argument("--plugin", action="append", default=[], metavar="FILE_OR_MODULE",
                   help="load this plugin first, as a scenario's plugins: entry does (a .py file, "
                        "relative to the working directory, or a module name); repeatable. It runs "
                        "the file's code.")
    p.set_defaults(func=cmd_list)


def _params(entry) -> str:
    """``name [default], ...`` of an entry's parameters."""
    if entry.params is not None and hasattr(entry.params, "model_fields"):
        out = []
        for name, field in entry.params.model_fields.items():
            if name in _NOT_PARAMS or field.exclude:
                continue
            key = field.alias or name
            if field.default is PydanticUndefined and field.default_factory is None:
                out.append(key)
            elif field.default_factory is None and field.default is not None:
                out.append(f"{key} [{field.default}]")
            else:
                out.append(f"{key} [optional]")
        return ", ".join(out)
    impl = entry.implementation
    required, optional = getattr(impl, "required", ()), getattr(impl, "optional", ())
    return ", ".join(list(required) + [f"{k} [optional]" for k in optional])


def describe(family: str) -> list[str]:
    """The lines ``dkfsim list <family>`` prints."""
    if family == "datasets":
        return ["datasets (scenario key dataset:)"] + [f"  {name}" for name in datasets()]
    reg = REGISTRIES[family]
    where = "columns of the tidy rows" if family == "metrics" else reg.where
    lines = [f"{family} ({where})"]
    for entry in reg.entries():
        lines.append(f"  {entry.name:<22} {entry.description}")
        params = _params(entry)
        if params:
            lines.append(f"  {'':<22}   parameters: {params}")
        if family == "estimators":
            packets = getattr(entry.implementation, "packets", "") or \
                "not described (its class's `packets` attribute: docs/extending.md)"
            lines.append(f"  {'':<22}   packets: {packets}")
    aliases = reg.aliases()
    if aliases:
        lines.append("  also accepted: " + ", ".join(f"{a} (= {n})" for a, n in aliases.items()))
    return lines


def cmd_list(args) -> int:
    for spec in args.plugin:
        load_plugin(spec)
    families = [args.what] if args.what else list(REGISTRIES) + ["datasets"]
    for i, family in enumerate(families):
        if i:
            say("")
        say("\n".join(describe(family)))
    return 0
