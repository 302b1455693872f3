"""What the hostile tests share: legitimate result folders to tamper with, and the CLI run as a
user runs it (a process of its own) with its CPU time and peak memory measured.

Time and memory bounds are on the child's own CPU seconds (``os.wait4``) and peak resident set
size (its ``VmHWM`` at exit, reported through a pipe), never wall time: the machine is shared.
``wait4``'s ``ru_maxrss`` is no measure of the child's memory: Linux carries the forking
process's resident size into the child's record, so it would include the pytest worker's.

A child is this test process forked (:func:`_forked`: dkfsim, its kernels and matplotlib already
loaded, the command run by ``dkfsim.cli.main`` with fresh standard streams, signals and warning
filters) unless it must be a fresh ``python -m dkfsim``: ``fresh=True``, an ``env`` (read at
import), ``python=`` code, or ``DKFSIM_TEST_FORK=0``.  Starting Python, dkfsim and matplotlib
afresh cost 1-1.5 s of CPU per call, most of this tier's time.  A forked child's peak memory is
what it grew by plus what a fresh process holds after those imports (measured once), and it
may reuse memory the test process had freed: a test whose point is a memory bound asks for a
fresh process (:meth:`Child.within` refuses a forked child a bound tighter than the default).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import resource
import shutil
import signal
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

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
    fresh: bool = True    # a fresh Python process (else this test process, forked)

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
        assert self.fresh or memory_mb >= MEMORY_LIMIT_MB, \
            "a test of a memory bound runs a fresh process: dkfsim_cli(..., fresh=True)"
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


def _readers(fds: list[int]):
    """Threads that read each of ``fds`` to its end (:func:`_wait` starts and joins them), and
    ``text(fd)``: what was read from ``fd``, decoded (empty for one not read)."""
    chunks: dict[int, list[bytes]] = {fd: [] for fd in fds}

    def read(fd: int) -> None:
        while block := os.read(fd, 1 << 16):
            chunks[fd].append(block)
    return ([threading.Thread(target=read, args=(fd,)) for fd in fds],
            lambda fd: b"".join(chunks.get(fd, ())).decode("utf-8", "replace"))


def _status_kb(field: bytes) -> int:
    """A ``kB`` figure of this process's /proc/self/status (``b"VmRSS:"``, ``b"VmHWM:"``)."""
    with open("/proc/self/status", "rb") as f:
        return int(next(line.split()[1] for line in f if line.startswith(field)))


def _wait(pid: int, kill, readers: list[threading.Thread], peak_r: int, timeout: float) -> tuple:
    """Start ``readers`` (of the child's output), wait for the child ``pid`` (``kill()`` after
    ``timeout`` s), read what it reported through ``peak_r``, join the readers: ``(wait status,
    resource usage, the report's bytes)``."""
    for r in readers:
        r.start()
    timer = threading.Timer(timeout, kill)
    timer.start()
    try:
        _, status, usage = os.wait4(pid, 0)
    finally:
        timer.cancel()
    os.set_blocking(peak_r, False)   # a grandchild may still hold the write end
    try:
        report = os.read(peak_r, 64)
    except BlockingIOError:
        report = b""
    os.close(peak_r)
    for r in readers:
        r.join()
    return status, usage, report


def dkfsim_cli(*args, cwd=None, env=None, timeout: float = 300, stdin=subprocess.DEVNULL,
               stdout=None, preexec=None, python=None, fresh: bool = False) -> Child:
    """``dkfsim ARGS`` in a child process (this one forked, or ``python -m dkfsim``: see the
    module); its resources are read with ``wait4``.

    ``stdout``: a file object to write the child's stdout to instead of capturing it;
    ``preexec``: run in the child before it starts (limits); ``python``: code run with ``-c``
    instead of ``-m dkfsim`` (``sys.argv[1:]`` are ARGS); ``fresh``: a fresh process.
    """
    if not (fresh or env or python is not None or os.environ.get("DKFSIM_TEST_FORK") == "0"):
        return _forked(args, cwd, timeout, stdin, stdout, preexec)
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
    out_fd, err_fd = (-1 if p.stdout is None else p.stdout.fileno()), p.stderr.fileno()
    readers, text = _readers([fd for fd in (out_fd, err_fd) if fd >= 0])
    status, usage, peak_kb = _wait(p.pid, p.kill, readers, peak_r, timeout)
    p.returncode = os.waitstatus_to_exitcode(status)
    out, err = text(out_fd), text(err_fd)
    for f in (p.stdout, p.stderr):
        if f is not None:
            f.close()
    return Child(p.returncode, out, err, usage.ru_utime + usage.ru_stime,
                 # killed before its exit handlers ran: only wait4's (inflated) figure is left
                 int(peak_kb) / 1024 if peak_kb.isdigit() else usage.ru_maxrss / 1024)


def _warm() -> float:
    """Load once in this process what the commands load (dkfsim's CLI, a run with its kernels,
    the report and matplotlib); the peak memory (MB) of a fresh process after those imports."""
    global _FRESH_MB
    if _FRESH_MB is None:
        import dkfsim.cli.main  # noqa: F401
        import dkfsim.report.html_report  # noqa: F401
        import dkfsim.report.plots  # noqa: F401
        dkfsim.run(dkfsim.load_scenario(CASE1, overrides=["steps=3"]))
        probe = dkfsim_cli(python="import dkfsim.cli.main, dkfsim.report.plots, matplotlib.pyplot", fresh=True)
        assert probe.returncode == 0, probe.stderr
        _FRESH_MB = probe.maxrss_mb
    return _FRESH_MB


_FRESH_MB: float | None = None


def _forked(args, cwd, timeout: float, stdin, stdout, preexec) -> Child:
    """:func:`dkfsim_cli` in this process, forked (see the module)."""
    base_mb = _warm()
    (out_r, out_w), (err_r, err_w), (peak_r, peak_w) = os.pipe(), os.pipe(), os.pipe()
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:
        for fd in (out_r, err_r, peak_r):
            os.close(fd)
        _child(args, cwd, stdin, out_w if stdout is None else stdout.fileno(), err_w, peak_w, preexec)
    for fd in (out_w, err_w, peak_w):
        os.close(fd)
    readers, text = _readers([out_r, err_r])
    status, usage, grown_kb = _wait(pid, lambda: os.kill(pid, signal.SIGKILL), readers, peak_r, timeout)
    out, err = text(out_r), text(err_r)
    for fd in (out_r, err_r):
        os.close(fd)
    return Child(os.waitstatus_to_exitcode(status), out, err, usage.ru_utime + usage.ru_stime,
                 base_mb + (int(grown_kb) / 1024 if grown_kb.isdigit() else float("inf")), fresh=False)


def _child(args, cwd, stdin, out_fd: int, err_fd: int, peak_fd: int, preexec) -> NoReturn:
    """The forked child of :func:`_forked`: standard streams on ``stdin`` (or /dev/null),
    ``out_fd`` and ``err_fd``, Python's default signals and warning filters, then ``dkfsim ARGS``;
    what its resident size grew by (kB) is written to ``peak_fd``.  Exits with the command's
    status (1 and a traceback if it raised)."""
    import faulthandler
    import io
    import traceback
    import warnings
    code = 1
    try:
        faulthandler.disable()
        signal.signal(signal.SIGINT, signal.default_int_handler)
        for sig in (signal.SIGTERM, signal.SIGALRM, signal.SIGXFSZ, signal.SIGCHLD):
            signal.signal(sig, signal.SIG_DFL)
        os.dup2(os.open(os.devnull, os.O_RDONLY) if stdin is subprocess.DEVNULL else stdin.fileno(), 0)
        os.dup2(out_fd, 1)
        os.dup2(err_fd, 2)
        sys.stdin = io.TextIOWrapper(io.FileIO(0, "r", closefd=False), encoding="utf-8")
        sys.stdout = io.TextIOWrapper(io.FileIO(1, "w", closefd=False), encoding="utf-8")
        sys.stderr = io.TextIOWrapper(io.FileIO(2, "w", closefd=False), encoding="utf-8",
                                      errors="backslashreplace", line_buffering=True)
        warnings.resetwarnings()                    # (also forgets every warning already shown)
        for category in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
            warnings.simplefilter("ignore", category)
        warnings.showwarning = warnings._showwarning_orig
        if "matplotlib.pyplot" in sys.modules:
            sys.modules["matplotlib.pyplot"].close("all")
        if cwd is not None:
            os.chdir(cwd)
        start_kb = _status_kb(b"VmRSS:")
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")                            # (the peak from here on)
        if preexec is not None:
            preexec()
        from dkfsim.cli.main import main
        sys.argv = [str(Path(dkfsim.__file__).with_name("__main__.py")), *map(str, args)]
        try:
            code = main(sys.argv[1:])
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 1
            if isinstance(exc.code, str):
                print(exc.code, file=sys.stderr)
        except BaseException:
            traceback.print_exc()
            code = 1
        for f in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                f.flush()
        os.write(peak_fd, str(max(0, _status_kb(b"VmHWM:") - start_kb)).encode())
    except BaseException:
        with contextlib.suppress(Exception):
            os.write(2, traceback.format_exc().encode())
    finally:
        os._exit(code if isinstance(code, int) else 1)


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


@pytest.fixture(scope="session")
def legit(tmp_path_factory) -> dict[str, Path]:
    """A run folder, a Monte Carlo folder and a sweep database (with its files), all small and
    untouched: tests copy them (:func:`copy_of`) before tampering.  Made once per test session
    (about 20 s): the first test process to need them makes them under a lock, in the
    directory every process of the session shares (pytest-xdist's workers' common parent), and
    every hostile module of every process reads the same ones."""
    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    d = shared / "legit"
    with open(shared / "legit.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)             # (released when the file closes)
        if not (d / "made").exists():
            shutil.rmtree(d, ignore_errors=True)     # (a process that failed half-way)
            d.mkdir()
            _make_legit(d)
            (d / "made").write_text("")
    return {"run": d / "run", "mc": d / "mc", "sweep": d / "sweep" / "s.sqlite"}


def _make_legit(d: Path) -> None:
    """The folders of :func:`legit`, made in ``d``."""
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


def copy_of(src: Path, dst_dir: Path, name: str | None = None) -> Path:
    """A copy of a legitimate folder (or a sweep database file) inside ``dst_dir``."""
    dst = dst_dir / (name or src.name)
    if src.is_dir():
        shutil.copytree(src, dst)
    else:
        dst_dir.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dst)
    return dst
