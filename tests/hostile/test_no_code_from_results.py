"""No code runs from a result folder someone sent you (issue 17).

Each hostile folder is built here from a legitimate one, with a payload that would create a file
if it ran: a pickled object array whose ``__reduce__`` opens a file, a ``plugins:`` key naming a
``.py`` file shipped in the folder (``source`` relative and absolute) or an importable module.
Every test asserts the file does not exist afterwards, and that the command either ends in a clean
error (exit 2, one paragraph) or, for a plugin key in an otherwise valid folder, succeeds without
importing it.  The payloads are shown to work (they do create the file when run directly), so a
test whose command did run them fails.  Names read from files reach the terminal escaped; a scan of
the package's source fails if an unpickling, ``eval``/``exec``, unsafe YAML or shell construct
appears.
"""

from __future__ import annotations

import ast
import json
import pickle
import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml
from hostile_kit import CASE1, ROOT, copy_of, dkfsim_cli, legit  # noqa: F401  (legit: a fixture)

import dkfsim
from dkfsim.core.errors import DkfsimError


class Payload:
    """Unpickling this opens (creates) ``path``: what an attacker's ``os.system`` would do."""

    def __init__(self, path: Path):
        self.path = str(path)

    def __reduce__(self):
        return (open, (self.path, "w"))


def test_the_payloads_work_when_run(tmp_path):
    """The payloads used below do create their file when they run, so their absence means
    they did not run."""
    hit = tmp_path / "unpickled"
    pickle.loads(pickle.dumps(Payload(hit)))
    assert hit.exists()
    plugin = write_plugin(tmp_path / "plugin_dir", tmp_path / "imported")
    dkfsim.load_scenario({**yaml.safe_load(CASE1.read_text()), "plugins": [str(plugin)], "steps": 5})
    assert (tmp_path / "imported").exists()


def write_plugin(folder: Path, marker: Path, name: str = "evil.py") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(f"open({str(marker)!r}, 'w').close()\n")
    return path


def add_object_array(npz: Path, key: str, marker: Path) -> None:
    """Add (or replace) ``key`` in ``npz`` by an object array holding a :class:`Payload`."""
    with np.load(npz) as z:
        arrays = {k: z[k] for k in z.files}
    arrays[key] = np.array([Payload(marker), "x"], dtype=object)
    np.savez(npz, **arrays)


# =========================================================================== pickles
@pytest.mark.parametrize("kind, npz, key", [("run", "run.npz", "x_fused"), ("run", "run.npz", "labels"),
                                             ("mc", "curves.npz", "components"),
                                             ("mc", "curves.npz", "estimates")])
def test_an_object_array_is_refused_and_never_unpickled(legit, tmp_path, kind, npz, key):  # noqa: F811
    marker = tmp_path / "PWNED"
    folder = copy_of(legit[kind], tmp_path)
    before = {f: f.read_bytes() for f in [folder / "report.html", *(folder / "figures").iterdir()]}
    add_object_array(folder / npz, key, marker)
    for command in (("plot", folder, "--format", "png"), ("report", folder)):
        dkfsim_cli(*command).clean_error(npz, key, "Python objects")
        assert not marker.exists(), command
    assert {f: f.read_bytes() for f in before} == before           # the earlier output is intact
    if kind == "run":
        with pytest.raises(DkfsimError, match="Python objects"):
            dkfsim.load_run(folder)
        assert not marker.exists()


# =========================================================================== plugins
def _tamper_summary(folder: Path, edit) -> None:
    path = folder / "summary.json"
    summary = json.loads(path.read_text())
    edit(summary)
    path.write_text(json.dumps(summary))


@pytest.mark.parametrize("kind", ["run", "mc"])
@pytest.mark.parametrize("source", ["absolute", "relative", "module"])
def test_a_plugins_key_in_a_summary_is_never_imported(legit, tmp_path, kind, source):  # noqa: F811
    """An otherwise valid folder whose stored scenario names a plugin (a file shipped in the
    folder, ``source`` absolute or relative to where the command runs, or a module on the path):
    plot, report and load_run succeed, show the key, and import nothing."""
    marker = tmp_path / "PWNED"
    folder = copy_of(legit[kind], tmp_path, "received")
    write_plugin(folder, marker)
    write_plugin(tmp_path / "modules", marker, "evil_module.py")
    spec = "evil_module" if source == "module" else "evil.py"
    src = {"absolute": str(folder / "x.yaml"), "relative": "received/x.yaml", "module": "x.yaml"}[source]

    def edit(s):
        s["scenario_config"]["plugins"] = [spec]
        s["source"] = src
    _tamper_summary(folder, edit)
    env = {"PYTHONPATH": str(tmp_path / "modules")}
    dkfsim_cli("plot", folder, "--format", "png", cwd=tmp_path, env=env).ok()
    assert not marker.exists()
    dkfsim_cli("report", folder, cwd=tmp_path, env=env).ok()
    assert not marker.exists()
    page = (folder / "report.html").read_text()
    assert "plugins:" in page and spec in page              # the stored scenario is shown
    assert "tracking" in page and "network" in page          # and validated: figures and drawing
    if kind == "run":
        res = dkfsim.load_run(folder)
        assert res.scenario.plugins == (spec,) and not marker.exists()


def test_a_stored_scenario_with_unknown_kinds_is_shown_not_validated(legit, tmp_path):  # noqa: F811
    """The plugin's estimator is unknown in this process: report shows the stored values and
    says why it has no drawing; load_run says the plugins were not imported and how to read it."""
    marker = tmp_path / "PWNED"
    folder = copy_of(legit["run"], tmp_path)
    write_plugin(folder, marker)

    def edit(s):
        s["scenario_config"]["plugins"] = ["evil.py"]
        s["scenario_config"]["estimators"].append({"kind": "evil_estimator"})
        s["source"] = str(folder / "x.yaml")
    _tamper_summary(folder, edit)
    dkfsim_cli("report", folder).ok()
    page = (folder / "report.html").read_text()
    assert "evil_estimator" in page and "never imports" in page
    with pytest.raises(DkfsimError, match="never imports") as err:
        dkfsim.load_run(folder)
    assert "evil.py" in str(err.value) and "evil_estimator" in str(err.value)
    assert not marker.exists()


def test_a_sweep_database_naming_a_plugin_imports_nothing(legit, tmp_path):  # noqa: F811
    marker = tmp_path / "PWNED"
    db = copy_of(legit["sweep"], tmp_path / "received")
    write_plugin(db.parent, marker)
    with sqlite3.connect(db) as conn:
        for h, text in conn.execute("SELECT param_hash, scenario_json FROM params").fetchall():
            cfg = json.loads(text)
            cfg["plugins"] = ["evil.py"]
            conn.execute("UPDATE params SET scenario_json=? WHERE param_hash=?", (json.dumps(cfg), h))
        definition = json.loads(conn.execute("SELECT value FROM meta WHERE key='definition'").fetchone()[0])
        definition["scenario_file"] = str(db.parent / "x.yaml")
        conn.execute("UPDATE meta SET value=? WHERE key='definition'", (json.dumps(definition),))
    dkfsim_cli("report", db).ok()
    assert not marker.exists()
    assert "evil.py" in db.with_name("s.report.html").read_text()
    dkfsim_cli("plot", db, "--format", "png").ok()
    assert not marker.exists()


def test_the_legitimate_folders_still_plot_and_report(legit, tmp_path):  # noqa: F811
    for kind in ("run", "mc", "sweep"):
        target = copy_of(legit[kind], tmp_path / kind)
        if kind != "sweep":
            out = dkfsim_cli("plot", target, "--format", "png").ok()
            assert "tracking.png" in out and "mse.png" in out
        dkfsim_cli("report", target).ok()
    assert dkfsim.load_run(tmp_path / "run" / "run").estimates[:2] == ["fused", "local"]


def test_running_a_scenario_still_imports_its_plugins(tmp_path):
    """``run`` is where the key acts (the security page says so): the plugin file is imported."""
    marker = tmp_path / "imported"
    write_plugin(tmp_path, marker)
    data = {**yaml.safe_load(CASE1.read_text()), "plugins": ["evil.py"], "steps": 5}
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(data))
    dkfsim_cli("run", tmp_path / "s.yaml", "--out", tmp_path / "out", "--quiet").ok()
    assert marker.exists()


# =========================================================================== terminal escapes
HOSTILE_NAME = "\x1b]0;PWNED\x07\x1b[2J\u202e"


def test_names_from_files_reach_the_terminal_escaped(tmp_path):
    data = yaml.safe_load(CASE1.read_text())
    data.update(name=HOSTILE_NAME, steps=20)
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(data))
    outputs = [dkfsim_cli("validate", tmp_path / "s.yaml").ok(),
               dkfsim_cli("run", tmp_path / "s.yaml", "--out", tmp_path / "out").ok()]
    data[HOSTILE_NAME] = 1                                   # an unknown key: the error names it
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(data))
    outputs.append(dkfsim_cli("validate", tmp_path / "bad.yaml").clean_error("unknown key"))
    for text in outputs:
        assert not set(text) & set("\x1b\x07\u202e"), repr(text)
        assert "\\x1b]0;PWNED\\x07\\x1b[2J\\u202e" in text, text


# =========================================================================== the source scan
#: Calls and names that unpickle, evaluate code, load YAML unsafely or start a shell.
BANNED_MODULES = {"pickle", "cPickle", "_pickle", "dill", "cloudpickle", "marshal", "shelve",
                  "jsonpickle", "joblib"}
BANNED_CALLS = {"eval", "exec", "compile", "__import__", "execfile"}
BANNED_ATTRIBUTES = {"unsafe_load", "unsafe_load_all", "full_load", "full_load_all", "UnsafeLoader",
                     "FullLoader", "read_pickle", "to_pickle", "system", "popen", "getoutput",
                     "getstatusoutput", "load_all"}
#: Modules allowed to import code by name: plugins (explicitly asked for by a scenario that runs,
#: or installed entry points), the optional dependencies (fixed names) and the kernel loader
#: (dkfsim's own kernel modules named in code, ``BORROWS``; it refuses any other name); and two
#: fixed tables of dkfsim's own modules imported on first use for start-up (decision 260): the
#: API of ``dkfsim/__init__.py`` and the sub-commands of ``cli/main.py``.
DYNAMIC_IMPORT_ALLOWED = {"dkfsim/core/registry.py", "dkfsim/core/extras.py", "dkfsim/core/jit.py",
                          "dkfsim/__init__.py", "dkfsim/cli/main.py"}
DYNAMIC_IMPORTS = {"import_module", "spec_from_file_location", "exec_module", "load_module"}


def unsafe_constructs(source: str, filename: str) -> list[str]:
    """Where ``source`` unpickles, evaluates code, loads YAML unsafely or starts a shell."""
    found = []
    for node in ast.walk(ast.parse(source, filename)):
        where = f"{filename}:{getattr(node, 'lineno', '?')}"
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            names = [a.name for a in node.names] + ([node.module] if isinstance(node, ast.ImportFrom)
                                                    and node.module else [])
            for n in names:
                if n.split(".")[0] in BANNED_MODULES:
                    found.append(f"{where}: imports {n}")
        elif isinstance(node, ast.keyword):
            if node.arg == "allow_pickle" and not (isinstance(node.value, ast.Constant)
                                                   and node.value.value is False):
                found.append(f"{where}: allow_pickle={ast.unparse(node.value)}")
            if node.arg == "shell" and not (isinstance(node.value, ast.Constant) and not node.value.value):
                found.append(f"{where}: shell={ast.unparse(node.value)}")
        elif isinstance(node, ast.Call):
            f = node.func
            if isinstance(f, ast.Name) and f.id in BANNED_CALLS:
                found.append(f"{where}: calls {f.id}()")
            if isinstance(f, ast.Attribute) and f.attr == "load" and isinstance(f.value, ast.Name) \
                    and f.value.id == "yaml":
                loader = next((k.value for k in node.keywords if k.arg == "Loader"),
                              node.args[1] if len(node.args) > 1 else None)
                if not (isinstance(loader, ast.Name) and loader.id.endswith("SafeLoader")):
                    found.append(f"{where}: yaml.load without a safe loader")
            if isinstance(f, ast.Attribute) and f.attr in DYNAMIC_IMPORTS \
                    and filename not in DYNAMIC_IMPORT_ALLOWED:
                found.append(f"{where}: imports code by name ({f.attr})")
        elif isinstance(node, ast.Attribute) and node.attr in BANNED_ATTRIBUTES:
            if node.attr in ("system", "popen") and not (isinstance(node.value, ast.Name)
                                                          and node.value.id == "os"):
                continue
            found.append(f"{where}: uses .{node.attr}")
        elif isinstance(node, ast.Attribute) and node.attr == "Loader" and isinstance(node.value, ast.Name) \
                and node.value.id == "yaml":
            found.append(f"{where}: uses yaml.Loader")
    return found


def test_the_package_has_no_unpickling_eval_unsafe_yaml_or_shell():
    package = ROOT / "dkfsim"
    files = sorted(package.rglob("*.py"))
    assert len(files) > 50
    found = []
    for path in files:
        found += unsafe_constructs(path.read_text(), path.relative_to(ROOT).as_posix())
    assert not found, "\n".join(found)


@pytest.mark.parametrize("snippet", [
    "import pickle", "from pickle import loads", "import cloudpickle as cp",
    "np.load(f, allow_pickle=True)", "np.load(f, allow_pickle=flag)", "eval('1')", "exec(code)",
    "yaml.load(text)", "yaml.load(text, Loader=yaml.Loader)", "yaml.unsafe_load(text)",
    "yaml.full_load(text)", "subprocess.run(cmd, shell=True)", "os.system('ls')", "os.popen('ls')",
    "pd.read_pickle(p)", "importlib.import_module(name)", "__import__('os')",
])
def test_the_scan_finds_each_construct(snippet):
    assert unsafe_constructs(snippet, "dkfsim/report/x.py"), snippet


def test_the_scan_accepts_the_safe_spellings():
    for snippet in ("np.load(f, allow_pickle=False)", "np.load(f)", "yaml.load(t, Loader=SafeLoader)",
                    "yaml.safe_load(t)", "subprocess.run(['ls'])", "re.compile('x')",
                    "importlib.import_module(n)"):
        assert not unsafe_constructs(snippet, "dkfsim/core/extras.py"), snippet
