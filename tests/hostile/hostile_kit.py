"""What the hostile tests share: legitimate result folders to tamper with, and the CLI run as a
user runs it (a real process) with its CPU time and peak memory measured.

Time and memory bounds are on the child's own CPU seconds (``os.wait4``) and peak resident set
size (its ``VmHWM`` at exit, reported through a pipe), never wall time: the machine is shared.
``wait4``'s ``ru_maxrss`` is no measure of the child's memory: Linux carries the forking
process's resident size into the child's record, so it would include the pytest worker's.
"""

from __future__ import annotations

import contextlib
import os
import resource
import shutil
import signal
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

import dkfsim

ROOT = Path(__file__).resolve().parents[2]
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"

#: Bounds of a clean refusal: CPU seconds (starting Python, dkfsim, numpy and matplotlib takes
#: 2-3 s of CPU) and peak resident memory (of a legitimate small folder: report ~160 MB, plot ~340 MB).
CPU_LIMIT = 30.0
MEMORY_LIMIT_MB = 800


@dataclass
class Child:
    """A finished ``dkfsim`` process: its exit status, output and the resources it used."""

    returncode: int
    stdout: str
    stderr: str
    cpu: float            # user + system seconds of the child (and the children it waited for)
    maxrss_mb: float      # peak resident set size of the child's own program (VmHWM)

    def clean_error(self, *words, cpu: float = CPU_LIMIT, memory_mb: float = MEMORY_LIMIT_MB) -> str:
        """Exit 2, no traceback, one paragraph naming every word, within the bounds."""
        err = self.stderr.strip()
        assert self.returncode == 2, (self.returncode, self.stdout[-2000:], self.stderr[-4000:])
        assert "Traceback" not in self.stderr and "\n" not in err, self.stderr[-4000:]
        for w in words:
            assert w in err, (w, err)
        self.within(cpu, memory_mb)
        return err

    def ok(self, cpu: float = CPU_LIMIT, memory_mb: float = MEMORY_LIMIT_MB) -> str:
        assert self.returncode == 0, (self.returncode, self.stdout[-2000:], self.stderr[-4000:])
        assert "Traceback" not in self.stderr, self.stderr[-4000:]
        self.within(cpu, memory_mb)
        return self.stdout

    def within(self, cpu: float, memory_mb: float) -> None:
        assert self.cpu < cpu, f"{self.cpu:.1f} s of CPU (bound {cpu} s)"
        assert self.maxrss_mb < memory_mb, f"{self.maxrss_mb:.0f} MB peak memory (bound {memory_mb} MB)"


def file_size_limit(limit: int):
    """A ``preexec`` for :func:`dkfsim_cli`: files of at most ``limit`` bytes (``ulimit -f``), the
    write beyond it failing with EFBIG as on a full disk (SIGXFSZ ignored, as a shell's
    ``trap '' XFSZ`` does)."""
    def apply():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
    return apply


#: Run first in every child: at exit, write the process's peak resident size (kB, ``VmHWM`` of
#: /proc/self/status) to the pipe named by the environment.  Silent if anything fails.
PEAK_REPORTER = """\
import atexit as _atexit, os as _os
def _report_peak(fd=int(_os.environ.pop("DKFSIM_TEST_PEAK_FD"))):
    try:
        with open("/proc/self/status", "rb") as f:
            _os.write(fd, next(l.split()[1] for l in f if l.startswith(b"VmHWM:")))
    except Exception:
        pass
_atexit.register(_report_peak)
"""
RUN_DKFSIM = "import runpy; runpy.run_module('dkfsim', run_name='__main__', alter_sys=True)"


def dkfsim_cli(*args, cwd=None, env=None, timeout: float = 300, stdin=subprocess.DEVNULL,
               stdout=None, preexec=None, python=None) -> Child:
    """``python -m dkfsim ARGS`` in a child process; its resources are read with ``wait4``.

    ``stdout``: a file object to write the child's stdout to instead of capturing it;
    ``preexec``: run in the child before it starts (limits); ``python``: code run with ``-c``
    instead of ``-m dkfsim`` (``sys.argv[1:]`` are ARGS).
    """
    peak_r, peak_w = os.pipe()
    full_env = {**os.environ, **(env or {}), "DKFSIM_TEST_PEAK_FD": str(peak_w)}
    code = PEAK_REPORTER + (RUN_DKFSIM if python is None else python)
    # Pipes, not files: a file-size limit set for the child must not cut its own messages.
    try:
        p = subprocess.Popen([sys.executable, "-c", code, *map(str, args)], cwd=cwd, env=full_env,
                             stdin=stdin, stdout=subprocess.PIPE if stdout is None else stdout,
                             stderr=subprocess.PIPE, preexec_fn=preexec, pass_fds=(peak_w,))
    finally:
        os.close(peak_w)
    chunks: dict[str, list[bytes]] = {"out": [], "err": []}
    readers = [threading.Thread(target=lambda f=f, k=k: chunks[k].append(f.read()))
               for f, k in ((p.stdout, "out"), (p.stderr, "err")) if f is not None]
    for r in readers:
        r.start()
    timer = threading.Timer(timeout, p.kill)
    timer.start()
    try:
        _, status, usage = os.wait4(p.pid, 0)
    finally:
        timer.cancel()
    p.returncode = os.waitstatus_to_exitcode(status)
    os.set_blocking(peak_r, False)   # a grandchild may still hold the write end
    try:
        peak_kb = os.read(peak_r, 64)
    except BlockingIOError:
        peak_kb = b""
    os.close(peak_r)
    for r in readers:
        r.join()
    for f in (p.stdout, p.stderr):
        if f is not None:
            f.close()
    return Child(p.returncode, b"".join(chunks["out"]).decode("utf-8", "replace"),
                 b"".join(chunks["err"]).decode("utf-8", "replace"), usage.ru_utime + usage.ru_stime,
                 # killed before its exit handlers ran: only wait4's (inflated) figure is left
                 int(peak_kb) / 1024 if peak_kb.isdigit() else usage.ru_maxrss / 1024)


class Hung(Exception):
    """A call in this process did not answer within its time (a FIFO it waits on)."""


@contextlib.contextmanager
def answers_within(seconds: float = 60):
    """Fail (raise :class:`Hung`) instead of waiting forever: SIGALRM interrupts even a blocked
    ``open`` of a FIFO."""
    def on_alarm(*_):
        raise Hung(f"no answer within {seconds} s")
    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def small_scenario() -> dkfsim.Scenario:
    return dkfsim.load_scenario(CASE1, overrides=["steps=40"])


@pytest.fixture(scope="module")
def legit(tmp_path_factory) -> dict[str, Path]:
    """A run folder, a Monte Carlo folder and a sweep database (with its files), all small and
    untouched: tests copy them (:func:`copy_of`) before tampering."""
    d = tmp_path_factory.mktemp("legit")
    sc = small_scenario()
    dkfsim.run(sc).save(d / "run")
    dkfsim.montecarlo(sc, runs=2).save(d / "mc")
    sweep_dir = d / "sweep"
    sweep_dir.mkdir()
    (sweep_dir / "s.yaml").write_text(yaml.safe_dump({
        "scenario": str(CASE1), "grid": {"links.default.latency.d_t": [0, 2]},
        "set": ["steps=30", "estimators=[{kind: centralized}]"], "runs": 2}))
    dkfsim.sweep(sweep_dir / "s.yaml", jobs=1, progress=False)
    # What a user had made of them before: a report and PNG figures (tests check they survive).
    from dkfsim.report.html_report import write_report
    from dkfsim.report.plots import load_folder, plot_folder
    for kind in ("run", "mc"):
        write_report(d / kind)
        plot_folder(load_folder(d / kind), d / kind / "figures", ("png",))
    write_report(sweep_dir / "s.sqlite")
    return {"run": d / "run", "mc": d / "mc", "sweep": sweep_dir / "s.sqlite"}


def copy_of(src: Path, dst_dir: Path, name: str | None = None) -> Path:
    """A copy of a legitimate folder (or a sweep database file) inside ``dst_dir``."""
    dst = dst_dir / (name or src.name)
    if src.is_dir():
        shutil.copytree(src, dst)
    else:
        dst_dir.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dst)
    return dst
