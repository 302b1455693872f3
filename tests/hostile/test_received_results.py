"""A received result folder never shows another file or hangs its reader (issue 30 §1-§4, §8).

Each case builds hostile input of one class -- several per class, not only the issue's example --
and checks the rule of docs/security.md:

1. reading a result folder, Monte Carlo folder or sweep database opens no file its contents
   name (the stored scenario is shown as stored), and no message quotes a data file's content;
2. a name holding terminal escapes reaches no terminal raw, through a figure's warnings either;
3. every file dkfsim reads is a regular file before it is opened (a FIFO never hangs a reader);
4. a reader stays within 300 MB + 10 x the file's size and answers in seconds;
8. a value of the wrong type anywhere in summary.json is refused by every reader, naming the key.

"Opens no file" is observed with an audit hook (``sys.addaudithook``): in this process for the
Python API, in the child for the command line.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import sqlite3
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from hostile_kit import CASE1, answers_within, copy_of, dkfsim_cli, legit  # noqa: F401  (legit: a fixture)
from tampering import edit_json, npz_arrays, npz_replace

import dkfsim
from dkfsim.cli.main import main
from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import parse_json

ROOT = Path(__file__).resolve().parents[2]
#: A line no output may show: the content of a file a result (or a scenario) names.
CANARY = "CANARY-30-SECRET"
#: Terminal escapes: retitle the window, ring the bell, clear the screen.
ESCAPES = "e\x1b]0;PWNED\x07\x1b[2J"
RAW = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f]")


def cli(*argv) -> tuple[int, str]:
    """``dkfsim ARGV`` in this process: (exit status, what it wrote on stderr and stdout)."""
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out), warnings.catch_warnings(), \
            answers_within():
        warnings.simplefilter("default")
        status = main([str(a) for a in argv])
    return status, err.getvalue() + out.getvalue()


@pytest.fixture
def elsewhere(tmp_path) -> Path:
    """A folder outside every result: the files a hostile result names live here."""
    d = tmp_path / "elsewhere"
    d.mkdir()
    (d / "secret.txt").write_text(f"{CANARY}-HEADER a b\n1,{CANARY}-CELL,3\n2 3 {CANARY}\n")
    os.mkfifo(d / "fifo")
    return d


_OPENED: list[str] | None = None


def _hook(event, args):
    if _OPENED is not None and event == "open" and args and isinstance(args[0], (str, bytes, os.PathLike)):
        _OPENED.append(os.path.realpath(os.fsdecode(args[0])))


sys.addaudithook(_hook)


@contextlib.contextmanager
def opened():
    """The real paths of every file opened inside the block (this process)."""
    global _OPENED
    seen: list[str] = []
    _OPENED = seen
    try:
        yield seen
    finally:
        _OPENED = None


def _inside(paths, folder: Path) -> list[str]:
    root = os.path.realpath(folder)
    return [p for p in paths if p == root or p.startswith(root + os.sep)]


#: The CLI in a child that says on stderr when it opens a file under $WATCHED.
WATCHED = """
import os, sys
watched = os.path.realpath(os.environ["WATCHED"])
def hook(event, args):
    if event == "open" and args and isinstance(args[0], (str, bytes, os.PathLike)):
        if os.path.realpath(os.fsdecode(args[0])).startswith(watched):
            os.write(2, b"OPENED-WATCHED ")
sys.addaudithook(hook)
from dkfsim.cli.main import main
sys.exit(main(sys.argv[1:]))
"""


# =========================================================================== 1. no file a result names
def _stored_naming(cfg: dict, how: str, target: str) -> dict:
    """The stored scenario ``cfg`` naming ``target`` (absolute, or relative to the scenario
    file a result names) in one of the ways a scenario names a file."""
    cfg = json.loads(json.dumps(cfg))
    if how == "track":
        cfg["mobility"] = {"vehicles": {"default": {"kind": "track", "file": target}},
                           "range": {"model": "disk", "radius": 1000.0}}
    elif how == "fcd":
        cfg["mobility"] = {"vehicles": {"default": {"kind": "sumo_fcd", "file": target, "vehicle": "v0"}},
                           "range": {"model": "disk", "radius": 1000.0}}
    elif how == "empirical":
        cfg["links"]["default"]["latency"] = {"model": "empirical", "file": target}
    elif how == "truth":
        cfg["truth"] = {"file": target}
    elif how == "relative":
        cfg["mobility"] = {"vehicles": {"default": {"kind": "track", "file": os.path.relpath(
            target, CASE1.parent)}}, "range": {"model": "disk", "radius": 1000.0}}
    return cfg


NAMING = ["track", "fcd", "empirical", "truth", "relative"]


@pytest.mark.parametrize("how", NAMING)
def test_a_run_folder_naming_a_file_shows_it_as_stored_and_opens_nothing(legit, tmp_path, elsewhere, how):  # noqa: F811
    """The issue's example was ``{kind: track, file: /etc/passwd}``: report.html and load_run
    showed the file's first line.  The report now shows the stored scenario as stored; load_run
    refuses naming the key (and how to read a folder one trusts); nothing under the folder the
    file is in is opened -- a FIFO there would have hung them."""
    folder = copy_of(legit["run"], tmp_path)
    target = str(elsewhere / ("fifo" if how == "fcd" else "secret.txt"))
    edit_json(folder / "summary.json", lambda s: s.update(scenario_config=_stored_naming(s["scenario_config"], how, target)))
    with opened() as seen:
        status, text = cli("report", folder)
        assert status == 0, text
        with answers_within(), pytest.raises(DkfsimError, match="data_files=True") as err:
            dkfsim.load_run(folder)
        with answers_within(), pytest.raises(DkfsimError, match="data_files=True"):
            dkfsim.load(folder)
    assert not _inside(seen, elsewhere), seen
    page = (folder / "report.html").read_text()
    assert CANARY not in page and CANARY not in str(err.value) and CANARY not in text
    assert "never opens the files it names" in page


@pytest.mark.parametrize("kind", ["mc", "sweep"])
def test_a_monte_carlo_folder_or_sweep_database_naming_a_file_opens_nothing(legit, tmp_path, elsewhere, kind):  # noqa: F811
    result = copy_of(legit[kind], tmp_path)
    target = str(elsewhere / "secret.txt")
    if kind == "mc":
        edit_json(result / "summary.json", lambda s: s.update(scenario_config=_stored_naming(
            s["scenario_config"], "track", target)))
    else:
        with contextlib.closing(sqlite3.connect(result)) as conn:
            for rowid, text in conn.execute("SELECT rowid, scenario_json FROM params").fetchall():
                conn.execute("UPDATE params SET scenario_json=? WHERE rowid=?",
                             (json.dumps(_stored_naming(json.loads(text), "empirical", target)), rowid))
            conn.commit()
    with opened() as seen:
        status, text = cli("report", result, "--out", tmp_path / "r.html")
        assert status == 0, text
        extra = ["--x", "d_t"] if kind == "sweep" else []
        status, text = cli("plot", result, "--format", "png", "--out", tmp_path / "figs", *extra)
        assert status == 0, text
        if kind == "mc":
            with pytest.raises(DkfsimError, match="data_files=True"):
                dkfsim.load(result)
    assert not _inside(seen, elsewhere), seen
    assert CANARY not in (tmp_path / "r.html").read_text()


def test_the_command_line_report_opens_no_file_the_result_names(legit, tmp_path, elsewhere):  # noqa: F811
    """The same in a child process, as a user runs it: its own audit hook sees every open."""
    folder = copy_of(legit["run"], tmp_path)
    edit_json(folder / "summary.json", lambda s: s.update(scenario_config=_stored_naming(
        s["scenario_config"], "fcd", str(elsewhere / "fifo"))))
    child = dkfsim_cli("report", folder, python=WATCHED, env={"WATCHED": str(elsewhere)}, timeout=120)
    child.ok()
    assert "OPENED-WATCHED" not in child.stderr


def test_a_trusted_folder_is_read_with_its_files(legit, tmp_path):  # noqa: F811
    """``data_files=True`` reads the files of a result one trusts (as before), and a file that
    is not a regular one is still refused cleanly, never waited on."""
    folder = copy_of(legit["run"], tmp_path)
    edit_json(folder / "summary.json", lambda s: s.update(scenario_config=_stored_naming(
        s["scenario_config"], "track", str(ROOT / "dkfsim" / "data" / "cicv5g" / "arterial_n8_v70_run03.txt"))))
    assert dkfsim.load_run(folder, data_files=True).scenario.mobility is not None
    os.mkfifo(tmp_path / "fifo")
    edit_json(folder / "summary.json", lambda s: s.update(scenario_config=_stored_naming(
        s["scenario_config"], "fcd", str(tmp_path / "fifo"))))
    with answers_within(), pytest.raises(DkfsimError, match="not a regular file"):
        dkfsim.load_run(folder, data_files=True)


@pytest.mark.parametrize("case", ["track column", "track cell", "empirical column", "empirical cell",
                                  "truth column", "truth cell"])
def test_no_message_quotes_the_content_of_a_data_file(elsewhere, case):
    """A scenario naming a file that is not the table it expects: the message names the file,
    the line and the column, never the file's content (the first line of /etc/passwd was shown
    as "its columns", a cell as "'...' is not a number")."""
    secret = elsewhere / "secret.txt"
    if case.endswith("cell"):
        secret.write_text(f"t x y\n0 0 0\n1 {CANARY} 0\n")
    data = dkfsim.load_scenario(CASE1, overrides=["steps=20"]).to_dict()
    columns = {"time_column": "t", "x_column": "x", "y_column": "y"} if case.endswith("cell") else {}
    if case.startswith("track"):
        data["mobility"] = {"vehicles": {"default": {"kind": "track", "file": str(secret), **columns}},
                            "range": {"model": "disk", "radius": 1000.0}}
    elif case.startswith("empirical"):
        data["links"]["default"]["latency"] = {"model": "empirical", "file": str(secret),
                                               "column": "x" if case.endswith("cell") else "delay_ms"}
    else:
        data["truth"] = {"file": str(secret), **columns}
        data["model"] = {"kind": "constant_velocity", "dims": 2, "T": 0.05, "q": 1.0}
    with pytest.raises(DkfsimError) as err:
        dkfsim.load_scenario(data)
    assert "secret.txt" in str(err.value) and CANARY not in str(err.value), str(err.value)


# =========================================================================== 2. terminal escapes
def _escaped_run(legit, tmp_path) -> Path:  # noqa: F811
    """A run folder whose scenario, first sensor and estimate ``centralized`` hold escapes."""
    folder = copy_of(legit["run"], tmp_path)

    def rename(s):
        s["scenario"] = ESCAPES
        s["scenario_config"]["sensors"][0]["name"] = ESCAPES
        s["estimates"] = [ESCAPES if e == "centralized" else e for e in s["estimates"]]
        for r in s["rows"]:
            r["estimate"] = ESCAPES if r["estimate"] == "centralized" else r["estimate"]
        s["traffic"] = {ESCAPES if k == "centralized" else k: v for k, v in s["traffic"].items()}
    edit_json(folder / "summary.json", rename)
    arrays = npz_arrays(folder / "run.npz")
    npz_replace(folder / "run.npz", **{f"{p}_{ESCAPES}": arrays[f"{p}_centralized"] for p in ("x", "P")
                                       if f"{p}_centralized" in arrays},
                x_centralized=None, P_centralized=None)
    lines = (folder / "rows.csv").read_text().replace(",centralized,", f",{ESCAPES},")
    (folder / "rows.csv").write_text(lines)
    return folder


@pytest.mark.parametrize("command", ["report", "plot", "compare"])
def test_names_holding_escapes_reach_no_terminal_raw(legit, tmp_path, command):  # noqa: F811
    """matplotlib printed "Glyph 27 missing from font" with the raw ESC on stderr: every name
    drawn goes through the one escaper, and so does every warning the CLI shows."""
    folder = _escaped_run(legit, tmp_path)
    argv = {"report": ("report", folder),
            "plot": ("plot", folder, "--format", "png"),
            "compare": ("plot", folder, legit["run"], "--compare", "--labels", ESCAPES, "b", "--title",
                        ESCAPES, "--format", "png", "--out", tmp_path / "cmp")}[command]
    child = dkfsim_cli(*argv)
    child.ok(cpu=60)
    assert not RAW.search(child.stderr + child.stdout), ascii(child.stderr[-2000:])


def test_a_sweep_with_escaped_names_reaches_no_terminal_raw(legit, tmp_path):  # noqa: F811
    db = copy_of(legit["sweep"], tmp_path)
    with contextlib.closing(sqlite3.connect(db)) as conn:
        conn.execute("UPDATE results SET estimate=? WHERE estimate='centralized'", (ESCAPES,))
        conn.execute("UPDATE params SET values_json=json_replace(values_json, '$.\"links.default.latency.d_t\"', ?)",
                     (ESCAPES + "x",))
        conn.commit()
    for argv in (("plot", db, "--format", "png", "--x", "d_t"), ("report", db)):
        child = dkfsim_cli(*argv)
        assert child.returncode in (0, 2) and "Traceback" not in child.stderr, child.stderr[-2000:]
        assert not RAW.search(child.stderr + child.stdout), ascii(child.stderr[-2000:])


#: A command whose code warns with a name holding escapes (as matplotlib does of a glyph).
WARNING_IN_A_COMMAND = """
import sys, warnings
from dkfsim.cli import list as list_cmd
from dkfsim.cli.main import main
def warn_then_list(args):
    warnings.warn("Glyph 27 (" + sys.argv[1] + ") missing from font(s) DejaVu Sans.", UserWarning)
    return 0
list_cmd.cmd_list = warn_then_list
sys.exit(main(["list"]))
"""


def test_a_warning_reaches_the_terminal_escaped():
    """A third-party warning carrying a name is shown through the escaper by the CLI."""
    child = dkfsim_cli(ESCAPES, python=WARNING_IN_A_COMMAND)
    assert "Glyph 27" in child.stderr and not RAW.search(child.stderr), ascii(child.stderr)


# =========================================================================== 3. regular files only
@pytest.mark.parametrize("special", ["fifo", "symlink to a fifo", "directory", "/dev/zero", "socket"])
def test_open_regular_refuses_what_is_not_a_regular_file_without_waiting(tmp_path, special):
    path = tmp_path / "x"
    if special == "fifo":
        os.mkfifo(path)
    elif special == "symlink to a fifo":
        os.mkfifo(tmp_path / "f")
        path.symlink_to(tmp_path / "f")
    elif special == "directory":
        path.mkdir()
    elif special == "socket":
        import socket
        s = socket.socket(socket.AF_UNIX)
        s.bind(str(path))
    else:
        path = Path(special)
    from dkfsim.core.files import open_regular  # (here: the test fails, not the module, without it)
    with answers_within(10), pytest.raises(DkfsimError, match="not a regular file|is a directory|cannot read"):
        open_regular(path, limit=1 << 20, what="data file")


@pytest.mark.parametrize("key", ["fcd", "track", "empirical", "truth"])
def test_a_fifo_named_by_a_scenario_is_refused_at_once(tmp_path, key):
    """validate, run (and load_run of a trusted folder) used to wait for a writer forever."""
    os.mkfifo(tmp_path / "fifo")
    data = _stored_naming(dkfsim.load_scenario(CASE1, overrides=["steps=20"]).to_dict(), key,
                          str(tmp_path / "fifo"))
    if key == "truth":
        data["model"] = {"kind": "constant_velocity", "dims": 2, "T": 0.05, "q": 1.0}
    (tmp_path / "s.yaml").write_text(json.dumps(data))
    dkfsim_cli("validate", tmp_path / "s.yaml", timeout=60).clean_error("fifo", "not a regular file")


@pytest.mark.parametrize("name", ["summary.json", "run.npz", "rows.csv"])
def test_a_fifo_inside_a_run_folder_hangs_no_reader(legit, tmp_path, name):  # noqa: F811
    folder = copy_of(legit["run"], tmp_path)
    (folder / name).unlink()
    os.mkfifo(folder / name)
    for argv in (("report", folder), ("plot", folder, "--format", "png")):
        child = dkfsim_cli(*argv, timeout=60)
        assert child.returncode in (0, 2) and "Traceback" not in child.stderr, child.stderr[-2000:]
    code = "import sys, dkfsim\ntry:\n    dkfsim.load_run(sys.argv[1])\nexcept dkfsim.DkfsimError as e:\n    print(e)"
    child = dkfsim_cli(folder, python=code, timeout=60)
    assert child.returncode == 0, child.stderr[-2000:]


def test_every_file_the_package_reads_is_opened_through_open_regular():
    """One mechanism: no module but core/files.py opens a file for reading itself (writers,
    /proc and /sys are listed).  A new reader that calls ``open`` fails this test."""
    allowed = {("dkfsim/core/files.py", None), ("dkfsim/core/resources.py", "/proc"),
               ("dkfsim/core/resources.py", "/sys"), ("dkfsim/core/folders.py", "/proc"),
               ("dkfsim/cli/main.py", "devnull"),
               ("dkfsim/core/jit.py", "hashlib.sha256("),    # the package's own kernel source
               ("dkfsim/core/npzfile.py", "ZipFile(fh)")}                           # fh from open_regular
    found = []
    for path in sorted((ROOT / "dkfsim").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        for no, line in enumerate(path.read_text().splitlines(), 1):
            code = line.split("#", 1)[0]
            if re.search(r"(?<![\w.])open\(|\.read_text\(|\.read_bytes\(|np\.load\(|ZipFile\(", code):
                if (rel, None) in allowed or any(rel == r and w in code for r, w in allowed if w):
                    continue
                if re.search(r"open\([^)]*[\"']w|mkstemp|fdopen|open_regular", code):
                    continue
                found.append(f"{rel}:{no}: {line.strip()}")
    assert not found, "files opened without open_regular:\n" + "\n".join(found)


# =========================================================================== 4. memory and time
@pytest.mark.slow
@pytest.mark.parametrize("what", ["a 40 MB string", "40 MB of escapes"])
def test_a_huge_string_in_summary_json_is_read_in_bounded_memory(legit, tmp_path, what):  # noqa: F811
    """A 40 MB string (under the 64 MiB limit) drove report to a MemoryError at 3.5 GB inside the
    JSON check: within 300 MB + 10 x the file's size now, and seconds of CPU."""
    folder = copy_of(legit["run"], tmp_path)
    value = "x" * 40_000_000 if what == "a 40 MB string" else "\n" * 20_000_000
    edit_json(folder / "summary.json", lambda s: s.update(fuzz_big=value))
    size_mb = (folder / "summary.json").stat().st_size / 2**20
    bound = 300 + 10 * size_mb
    dkfsim_cli("report", folder, fresh=True).ok(cpu=60, memory_mb=bound)
    dkfsim_cli("plot", folder, "--format", "png", fresh=True).ok(cpu=60, memory_mb=bound)


@pytest.mark.slow
def test_a_huge_cell_in_a_sweep_database_is_read_in_bounded_memory(legit, tmp_path):  # noqa: F811
    db = copy_of(legit["sweep"], tmp_path)
    with contextlib.closing(sqlite3.connect(db)) as conn:
        conn.execute("UPDATE params SET values_json=? WHERE idx=0", (json.dumps({"x": "y" * 40_000_000}),))
        conn.commit()
    child = dkfsim_cli("report", db, fresh=True)
    assert child.returncode in (0, 2) and "Traceback" not in child.stderr
    child.within(60, 300 + 10 * db.stat().st_size / 2**20)


def test_the_json_check_is_linear():
    """The nesting check on the text: a string of 20 MB, of 10 MB of escapes and an unterminated
    one each pass in well under a second of CPU (the earlier pattern took 16 s and 4.8 GB on 40
    MB; an unterminated string of escaped quotes would have been quadratic)."""
    import time
    for text in ('{"a": "' + "x" * 20_000_000 + '"}', '["' + "\\n" * 5_000_000 + '"]',
                 '["' + '\\"' * 2_000_000, "[" * 100 + "]" * 100):
        start = time.process_time()
        with contextlib.suppress(DkfsimError), answers_within(60):
            parse_json(text, "t.json", "test")
        assert time.process_time() - start < 5
    with pytest.raises(DkfsimError, match="nested deeper"):
        parse_json("[" * 100 + "]" * 100, "t.json", "test")


def _fcd(path: Path, body_attr: str = "", text: str = "") -> None:
    path.write_text(f'<fcd-export><timestep time="0"><vehicle id="v0" x="0" y="0"{body_attr}/>{text}'
                    '</timestep><timestep time="1"><vehicle id="v0" x="1" y="0"/></timestep></fcd-export>')


def _fcd_scenario(tmp_path: Path, fcd: Path) -> Path:
    data = dkfsim.load_scenario(CASE1, overrides=["steps=20"]).to_dict()
    data["mobility"] = {"vehicles": {"default": {"kind": "sumo_fcd", "file": str(fcd), "vehicle": "v0"}},
                        "range": {"model": "disk", "radius": 1000.0}}
    (tmp_path / "s.yaml").write_text(json.dumps(data))
    return tmp_path / "s.yaml"


@pytest.mark.slow
@pytest.mark.parametrize("what", ["a 100 MB attribute", "50 MB of text"])
def test_a_huge_fcd_element_is_refused_at_once(tmp_path, what):
    """A 100 MB attribute took 2.7 GB and 46 s (expat buffers and re-scans it at every chunk)."""
    fcd = tmp_path / "f.xml"
    with open(fcd, "w") as fh:
        fh.write('<fcd-export><timestep time="0"><vehicle id="v0" x="0" y="0" ')
        fh.write('type="' + "t" * 100_000_000 + '"/>' if what == "a 100 MB attribute" else '/>' + "text " * 10_000_000)
        fh.write("</timestep></fcd-export>")
    dkfsim_cli("validate", _fcd_scenario(tmp_path, fcd), fresh=True).clean_error("f.xml", "without a '>'", cpu=20,
                                                                   memory_mb=600)


@pytest.mark.parametrize("coordinate", ["1e308", "-1e308", "1e10"])
def test_fcd_coordinates_beyond_any_road_are_refused_without_warnings(tmp_path, coordinate):
    """x = +-1e308 gave a raw numpy RuntimeWarning and infinite speeds."""
    fcd = tmp_path / "f.xml"
    _fcd(fcd, f' x2="{coordinate}"')
    fcd.write_text(fcd.read_text().replace('x="1"', f'x="{coordinate}"'))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(DkfsimError, match="beyond"):
            dkfsim.load_scenario(_fcd_scenario(tmp_path, fcd))


def test_fcd_times_too_close_for_their_distance_are_refused(tmp_path):
    fcd = tmp_path / "f.xml"
    fcd.write_text('<fcd-export><timestep time="1e-300"><vehicle id="v0" x="0" y="0"/></timestep>'
                   '<timestep time="2e-300"><vehicle id="v0" x="1e9" y="0"/></timestep></fcd-export>')
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(DkfsimError, match="speed"):
            dkfsim.load_scenario(_fcd_scenario(tmp_path, fcd))


# =========================================================================== 8. wrong types
RUN_TYPES = {
    "traffic.<e>.per_link a string": (lambda s: s["traffic"]["fused"].update(per_link="abc"), "traffic.fused.per_link"),
    "packets.sent a string": (lambda s: s["packets"].update(sent="12"), "packets.sent"),
    "per_link row count a string": (lambda s: s["per_link"][0].update(sent="x"), "per_link.0.sent"),
    "late_per_node a number": (lambda s: s["traffic"]["fused"].update(late_per_node=5), "traffic.fused.late_per_node"),
    "facts of an estimate a list": (lambda s: s["facts"].update(ci=[1, 2]), "facts.ci"),
    "metrics of an estimate a string": (lambda s: s["metrics"].update(fused="x"), "metrics.fused"),
    "a version a number": (lambda s: s["versions"].update(numpy=1), "versions.numpy"),
    "n_links a string": (lambda s: s.update(n_links="22"), "n_links"),
    "a per_link row of a rated link without its delays": (
        lambda s: s["per_link"][0].update(utilisation=0.5), "per_link.0.queueing_delay_mean"),
    "traffic.<e>.in_flight negative": (lambda s: s["traffic"]["fused"].update(in_flight=-1),
                                       "traffic.fused.in_flight"),
}


@pytest.mark.parametrize("case", list(RUN_TYPES))
def test_a_value_of_the_wrong_type_in_summary_json_is_refused_naming_the_key(legit, tmp_path, case):  # noqa: F811
    """load_run on ``traffic.<estimate>.per_link`` as a string was a TypeError: every reader
    refuses now, naming the key."""
    folder = copy_of(legit["run"], tmp_path)
    edit, key = RUN_TYPES[case]
    edit_json(folder / "summary.json", edit)
    with pytest.raises(DkfsimError, match=re.escape(key)):
        dkfsim.load_run(folder)
    for argv in (("report", folder, "--out", tmp_path / "r.html"),
                 ("plot", folder, "--format", "png", "--out", tmp_path / "figs")):
        status, text = cli(*argv)
        assert status == 2 and key in text and "Traceback" not in text, text


MC_TYPES = {
    "jobs a string": (lambda s: s.update(jobs="2"), "jobs"),
    "notes a list": (lambda s: s.update(notes=["x"]), "notes"),
    "wall_time_s negative": (lambda s: s.update(wall_time_s=-1.0), "wall_time_s"),
}


@pytest.mark.parametrize("case", list(MC_TYPES))
def test_a_monte_carlo_summary_with_a_wrong_type_is_refused_naming_the_key(legit, tmp_path, case):  # noqa: F811
    folder = copy_of(legit["mc"], tmp_path)
    edit, key = MC_TYPES[case]
    edit_json(folder / "summary.json", edit)
    with pytest.raises(DkfsimError, match=re.escape(key)):
        dkfsim.load(folder)
    status, text = cli("report", folder, "--out", tmp_path / "r.html")
    assert status == 2 and key in text, text


def test_a_monte_carlo_of_recorded_tracks_runs_on_worker_processes():
    """Each track vehicle's SINR look-up was a closure: a Monte Carlo of mobility_convoy with
    more than one worker ended in a pickling traceback."""
    sc = dkfsim.load_scenario(ROOT / "scenarios" / "mobility_convoy.yaml",
                              overrides=["steps=10", "estimators=[{kind: centralized}]"])
    res = dkfsim.montecarlo(sc, runs=2, jobs=2)
    assert res.runs == 2 and np.isfinite(res.mse).all()
