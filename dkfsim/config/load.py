"""Loading a scenario: a file, a mapping or a Scenario, plus overrides, validated once.

:func:`load_scenario` reads YAML safely (:mod:`dkfsim.config.yaml`), applies
``--set`` overrides (:mod:`dkfsim.config.overrides`), imports the plugins the
scenario names (only when asked to: a scenario read back from a result is data,
``import_plugins=False``; docs/security.md), and validates everything in one pass
(:class:`~dkfsim.config.schema.Scenario`); any problem is a
:class:`~dkfsim.core.errors.ScenarioError` naming the file and the key.
"""

from __future__ import annotations

import copy
import os
from pathlib import Path
from typing import Any, Mapping, Sequence

import yaml
from pydantic import ValidationError

from dkfsim.components.latency import STORED_FILE_REFUSAL
from dkfsim.config.messages import convert
from dkfsim.config.overrides import apply_override
from dkfsim.config.schema import Scenario, scenario_hash  # noqa: F401  (re-exported)
from dkfsim.config.yaml import parse_yaml, yaml_error_text
from dkfsim.core.errors import DkfsimError, ScenarioError
from dkfsim.core.files import MAX_YAML_BYTES, check_plain_data, clip, read_text
from dkfsim.core.params import NAME_LIMIT
from dkfsim.core.registry import load_plugin


def _parse_yaml(text: str, source: str) -> Any:
    try:
        return parse_yaml(text)
    except yaml.YAMLError as err:
        raise ScenarioError(yaml_error_text(err), source=source) from None


def _load_plugins(data: dict, label: str, base_dir: str | os.PathLike | None) -> None:
    """Import the modules and files a scenario's ``plugins:`` key names (they register
    components the rest of the file may use)."""
    plugins = data.get("plugins") or []
    if not isinstance(plugins, (list, tuple)):
        raise ScenarioError("must be a list of module names or .py files", source=label, path="plugins")
    for i, spec in enumerate(plugins):
        if not isinstance(spec, str) or not spec.strip():
            raise ScenarioError(f"must be a module name or a .py file, got {spec!r}", source=label,
                                path=f"plugins.{i}")
        try:
            load_plugin(spec, base_dir)
        except DkfsimError as err:
            raise ScenarioError(str(err), source=label, path=f"plugins.{i}") from None


def load_scenario(source: str | os.PathLike | Mapping | Scenario,
                  overrides: Sequence[str] = (), *, base_dir: str | os.PathLike | None = None,
                  import_plugins: bool = True, data_files: bool = True) -> Scenario:
    """Load, override and validate a scenario.

    ``source`` is a path to a YAML file, a mapping, or a Scenario (re-validated
    from its ``to_dict`` so that overrides apply).  ``overrides`` are
    ``dotted.key=value`` strings, the value parsed as YAML, applied to the raw
    mapping before validation (``sensors.0.R=[[2.0]]``, ``links.d_t=5``).
    ``base_dir`` is where the relative ``file:`` paths of a mapping resolve
    (default: the working directory); a file's own folder is used for a
    path, and a Scenario keeps the folder it was loaded with.
    ``import_plugins``: import the modules and files of the ``plugins:`` key
    before validating (what running a scenario does).  False for a scenario
    read back from a result folder or sweep database: the key is kept as a
    value, and only the components already registered in this process (entry
    points included) are known -- reading results never imports anything.
    ``data_files``: read the tables and FCD files its ``file:`` keys name (what running a
    scenario does).  False for a scenario read back from a result: a ``file:`` key is then a
    :class:`ScenarioError` naming it, and no file is opened (shipped ``dataset:`` keys are read).
    Raises :class:`ScenarioError` on any problem.
    """
    if isinstance(overrides, str):
        overrides = (overrides,)
    path: str | None = None
    if isinstance(source, Scenario):
        label = source.source or "<dict>"
        path = source.source
        base_dir = source.base_dir
        data: Any = source.to_dict()
    elif isinstance(source, (str, os.PathLike)):
        label = path = os.fspath(source)
        try:
            text = read_text(path, limit=MAX_YAML_BYTES, what="scenario file")
        except DkfsimError as err:
            raise ScenarioError(str(err)) from None
        data = _parse_yaml(text, label)
    elif isinstance(source, Mapping):
        label = "<dict>"
        try:
            check_plain_data(source)
        except DkfsimError as err:
            raise ScenarioError(str(err), source=label) from None
        data = copy.deepcopy(dict(source))
    else:
        raise TypeError(f"load_scenario needs a path, a mapping or a Scenario, "
                        f"got {type(source).__name__}")
    if data is None:
        raise ScenarioError("empty file: expected a mapping of scenario keys", source=label)
    if not isinstance(data, dict):
        raise ScenarioError(f"top level must be a mapping of scenario keys, got "
                            f"{type(data).__name__}", source=label)
    if "scenario" in data and ("grid" in data or "runs" in data) and "sensors" not in data:
        raise ScenarioError("this is a sweep file (it names a scenario and a grid), not a scenario: "
                            "run it with 'dkfsim sweep'", source=label)
    override_keys: dict[str, str] = {}
    for text in overrides:
        key = apply_override(data, text, label)
        override_keys.pop(key, None)    # (kept in the order applied: the last to cover a key set it)
        override_keys[key] = text
    if "name" not in data and path is not None:
        data["name"] = Path(path).stem[:NAME_LIMIT]
    if path is not None and base_dir is None:
        # Relative data files (traces, tracks) resolve against the file's folder.
        base_dir = Path(path).resolve().parent
    base_dir = None if base_dir is None else str(base_dir)
    if import_plugins:
        _load_plugins(data, label, base_dir)
    try:
        scenario = Scenario.model_validate(data, context={"base_dir": base_dir, "data_files": data_files})
    except ValidationError as exc:
        raise convert(exc, data, label, override_keys) from None
    scenario.set_source(path, base_dir)
    return scenario


def stored_scenario(config: Any, *, source: Any = None, label: str, data_files: bool = False) -> Scenario:
    """A scenario read back from a result (``summary.json``, a sweep database), validated as data.

    Its ``plugins:`` key is never acted on (reading results never imports anything,
    docs/security.md): only the components already registered in this process count,
    those of installed entry-point plugins included.  Nor are the files its ``file:`` keys
    name opened (a received result may name any file of the machine): such a scenario is a
    :class:`ScenarioError` naming the key, unless ``data_files`` (the caller trusts the
    result: :func:`dkfsim.load_run` with ``data_files=True``), when relative data files
    resolve against the folder of ``source``, the scenario file the result names.  ``label``
    names the file the scenario was read from in messages.  Raises :class:`ScenarioError`;
    when a kind is unknown and the stored scenario lists plugins, the message says that
    they were not imported and how to read the result anyway.
    """
    if not isinstance(config, dict):
        raise ScenarioError(f"the stored scenario must be a mapping, got {type(config).__name__}",
                            source=label, path="scenario_config")
    base_dir = None
    if isinstance(source, str) and source.strip():
        try:
            base_dir = str(Path(source).resolve().parent)
        except (OSError, ValueError, RuntimeError):
            base_dir = None
    try:
        return load_scenario(config, base_dir=base_dir, import_plugins=False, data_files=data_files)
    except ScenarioError as err:
        if STORED_FILE_REFUSAL in err.reason:
            raise ScenarioError(f"the stored scenario names a data file ({err.path}), and reading a result "
                                "never opens the files it names (they could be any file on this machine); "
                                "if you trust this result, read it with dkfsim.load_run(..., data_files=True)",
                                source=label) from None
        plugins = config.get("plugins")
        if isinstance(plugins, (list, tuple)) and plugins:
            names = ", ".join(clip(p, 60) for p in plugins[:5]) + (", ..." if len(plugins) > 5 else "")
            raise ScenarioError(
                f"the stored scenario cannot be validated with the components loaded in this process "
                f"({err.reason}); it names plugins ({names}), which reading a result never imports: "
                "import the ones you trust yourself, then read it again", source=label) from None
        raise ScenarioError(f"the stored scenario is not valid here: {err.reason}"
                            + (f" (at {err.path})" if err.path else ""), source=label) from None
