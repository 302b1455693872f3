"""Writing result folders: checked up front, swapped in atomically, one number encoding.

Every command that writes a folder (``run``, ``montecarlo``, ``maxdelay``)
goes through :func:`check_target` *before* it computes anything and
:func:`staged` when it writes:

* the target must be a new folder, an empty one, or one that dkfsim wrote
  (it holds the marker file :data:`MARKER`, or only the names dkfsim
  writes); a file, a folder of someone else's files or an unwritable
  parent is refused with a clear error before any work is done;
* the whole output is written into a fresh folder beside the target and
  then exchanged with it in one step (``renameat2(RENAME_EXCHANGE)`` on
  Linux; elsewhere two renames, the previous folder kept as
  ``.<name>.old-*`` if the process dies between them).  A reader sees the
  complete previous output or the complete new one, never a truncated file
  or files of two runs side by side.  The previous output is deleted once
  the new one is in place.

JSON goes through :mod:`dkfsim.core.encoding`, the one number encoding.
"""

from __future__ import annotations

import contextlib
import csv
import ctypes
import ctypes.util
import json
import os
import shutil
import tempfile
from pathlib import Path

from dkfsim.core.encoding import csv_cell, to_json
from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import open_regular, shown

#: The file that marks a folder as written by dkfsim (safe to replace).
MARKER = ".dkfsim-output"
#: Names dkfsim writes into a result folder (a folder holding only these is ours).
KNOWN_OUTPUTS = frozenset({MARKER, "summary.json", "run.npz", "runs.csv", "curves.npz",
                           "maxdelay.json", "maxdelay.png", "maxdelay.pdf", "figures",
                           "rows.csv", "report.html"})


def json_text(obj) -> str:
    """``obj`` as indented standard JSON text (converted first, so a failure writes nothing)."""
    return json.dumps(to_json(obj), indent=2, allow_nan=False) + "\n"


def write_json(path, obj) -> None:
    """Write ``obj`` as JSON, atomically (a temporary file renamed over ``path``)."""
    write_text(path, json_text(obj))


@contextlib.contextmanager
def replacing(path, mode: str = "w", newline: str | None = None):
    """A file opened for writing beside ``path`` and renamed over it when the block ends
    without an error (removed otherwise): readers see the old file or the whole new one.  The
    temporary file is created exclusively (``mkstemp``), so a link planted under its name is
    never written through.  ``mode``: ``"w"`` (UTF-8 text) or ``"wb"`` (bytes, e.g. a figure)."""
    path = Path(path)
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name[:100]}.", suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, mode, newline=newline, encoding=None if "b" in mode else "utf-8") as fh:
            yield fh
        os.chmod(tmp, file_mode())
        os.replace(tmp, path)
    except BaseException as exc:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        if isinstance(exc, OSError):       # a full disk, a name too long, no permission, ...
            raise WriteFailed(path, exc) from None
        raise


class WriteFailed(DkfsimError):
    """A file could not be written (:func:`replacing`): the OS's reason, the file named; nothing
    of it is left (the temporary file is removed, an earlier file of that name is untouched)."""

    def __init__(self, path, exc: OSError):
        self.strerror = exc.strerror or str(exc)
        self.filename = str(path)
        super().__init__(f"cannot write {shown(path)} ({self.strerror}); nothing was written there")


def write_csv(path, columns, rows) -> None:
    """Write a CSV table atomically: a header, then ``rows`` (sequences of cells, encoded by
    :func:`dkfsim.core.encoding.csv_cell`)."""
    with replacing(path, newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(columns)
        for row in rows:
            w.writerow([csv_cell(v) for v in row])


def write_text(path, text: str) -> None:
    """Write a text file atomically."""
    with replacing(path) as fh:
        fh.write(text)


# =========================================================================== folders
# =========================================================================== staging folders
#: The file inside a staging folder that says which process writes it (to prove it dead later).
OWNER = ".dkfsim-staging"


def _process_identity(pid: int) -> dict | None:
    """What identifies process ``pid`` on this machine since boot (Linux ``/proc``), or None."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            start = int(fh.read().rsplit(b")", 1)[1].split()[19])      # field 22: start time
        with open("/proc/sys/kernel/random/boot_id") as fh:
            boot = fh.read().strip()
    except (OSError, ValueError, IndexError):
        return None
    return {"pid": pid, "start": start, "boot": boot, "host": os.uname().nodename}


def _stage_dir(target: Path, kind: str) -> Path:
    """A new staging folder beside ``target`` (``.NAME.new-PID-XXXX``), marked with its owner;
    removed again if it cannot be marked (a full disk)."""
    stage = Path(tempfile.mkdtemp(prefix=f".{target.name}.{kind}-{os.getpid()}-", dir=target.absolute().parent))
    try:
        _mark_owner(stage)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    return stage


def _mark_owner(folder: Path) -> None:
    me = _process_identity(os.getpid())
    if me is not None:
        (folder / OWNER).write_text(json.dumps(me))


def _provably_dead(stage: Path) -> bool:
    """True when the process that made ``stage`` cannot be running any more: it ran on this
    machine (same host name) and either the machine rebooted since, or no process with its pid
    and start time exists.  Anything else -- no owner file, another host -- is left alone."""
    try:
        with open_regular(stage / OWNER, limit=4096, what="staging owner file") as fh:   # (a FIFO: no)
            owner = json.loads(fh.read())
        pid, host, boot, start = int(owner["pid"]), owner["host"], owner["boot"], owner["start"]
    except (OSError, ValueError, KeyError, TypeError, DkfsimError):
        return False
    me = _process_identity(os.getpid())
    if me is None or host != me["host"]:
        return False
    if boot != me["boot"]:
        return True
    now = _process_identity(pid)
    return now is None or now["start"] != start


def remove_dead_staging(target: Path) -> list[Path]:
    """Remove the staging folders of ``target`` (``.NAME.new-*``, ``.NAME.old-*``) left by a
    process killed while writing (``kill -9``, a power cut) that :func:`_provably_dead` shows
    dead.  A dead ``.old`` folder is the previous output of an interrupted two-rename swap: it
    is put back when ``target`` is missing.  Returns what was removed or restored."""
    parent = target.absolute().parent
    done: list[Path] = []
    try:
        entries = list(parent.iterdir())
    except OSError:
        return done
    for e in entries:
        for kind in ("new", "old"):
            if e.name.startswith(f".{target.name}.{kind}-") and e.is_dir() and not e.is_symlink() \
                    and _provably_dead(e):
                with contextlib.suppress(OSError):
                    if kind == "old" and not target.exists() and not target.is_symlink():
                        (e / OWNER).unlink(missing_ok=True)
                        os.rename(e, target)
                    else:
                        shutil.rmtree(e)
                    done.append(e)
    return done


def _owned(entries: list[str]) -> bool:
    return MARKER in entries or all(e in KNOWN_OUTPUTS for e in entries)


def check_target(out_dir, flag: str = "--out") -> Path:
    """Check that ``out_dir`` can receive a result folder; return it as a Path.

    Called before any work.  Creates missing parent folders and probes that a
    folder can be made beside the target (which is where :func:`staged`
    writes).  Raises :class:`DkfsimError` naming ``flag``.
    """
    text = os.fspath(out_dir) if out_dir is not None else ""
    if not str(text).strip():
        raise DkfsimError(f"{flag}: empty path; give the folder to write into")
    label = shown(text)
    out = Path(text)
    try:
        _check_existing(out, flag, label)
        parent = out.absolute().parent
        parent.mkdir(parents=True, exist_ok=True)
        probe = tempfile.mkdtemp(prefix=f".{out.name[:100]}.probe-", dir=parent)
        os.rmdir(probe)
    except OSError as exc:           # a name too long, no permission, a full disk, ...
        raise DkfsimError(f"{flag} {label}: cannot write there ({exc.strerror or exc}); nothing was "
                          "written") from None
    return out


def _check_existing(out: Path, flag: str, label: str) -> None:
    """An existing ``out`` must be a folder dkfsim wrote (or an empty one)."""
    remove_dead_staging(out)
    if out.exists() or out.is_symlink():
        if not out.is_dir():
            raise DkfsimError(f"{flag} {label}: exists and is not a folder; give a folder name")
        try:
            entries = sorted(os.listdir(out))
        except OSError as exc:
            raise DkfsimError(f"{flag} {label}: cannot read the folder ({exc.strerror})") from None
        if entries and not _owned(entries):
            names = ", ".join(shown(e, 60) for e in entries[:5]) + (", ..." if len(entries) > 5 else "")
            raise DkfsimError(f"{flag} {label}: the folder holds files dkfsim did not write ({names}); "
                              "it would be replaced as a whole: choose a new or empty folder")
        for name in ("run.npz", "summary.json", "runs.csv", "curves.npz", "maxdelay.json"):
            if (out / name).is_dir():
                raise DkfsimError(f"{flag} {label}: {name} inside it is a folder; remove it or "
                                  "choose another folder")


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2``); False when not supported."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    AT_FDCWD, RENAME_EXCHANGE = -100, 2
    if fn(AT_FDCWD, os.fsencode(a), AT_FDCWD, os.fsencode(b), RENAME_EXCHANGE) == 0:
        return True
    return False


def _swap_in(stage: Path, target: Path) -> None:
    if not target.exists() and not target.is_symlink():
        os.rename(stage, target)
        return
    if _exchange(stage, target):
        shutil.rmtree(stage, ignore_errors=True)          # now holds the previous output
        return
    old = _stage_dir(target, "old")
    shutil.rmtree(old)
    os.rename(target, old)
    _mark_owner(old)                # (a kill now leaves it to remove_dead_staging to put back)
    os.rename(stage, target)
    shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def staged(out_dir, what: str, flag: str = "--out"):
    """Write a result folder atomically: ``with staged(DIR, "run") as tmp: write into tmp``.

    On success the folder replaces ``DIR`` as a whole; on any error (or a
    kill) ``DIR`` is untouched and the staging folder is removed.
    """
    target = check_target(out_dir, flag)
    existed = target.exists()
    stage: Path | None = None
    try:
        try:
            stage = _stage_dir(target, "new")        # (a full disk may refuse its owner file already)
            yield stage
            (stage / OWNER).unlink(missing_ok=True)
            (stage / MARKER).write_text(f"written by dkfsim {what}; the folder is replaced as a whole "
                                        "by the next command that writes here\n")
            os.chmod(stage, 0o777 & ~_umask())
            _swap_in(stage, target)
        except (OSError, WriteFailed) as exc:     # a full disk (ENOSPC), a file-size limit (EFBIG), ...
            kept = f"{shown(out_dir)} holds what it held before" if existed else "nothing was written"
            name = f": {shown(Path(exc.filename).name, 60)}" if exc.filename else ""
            raise DkfsimError(f"{flag} {shown(out_dir)}: cannot write the results ({exc.strerror or exc}"
                              f"{name}); {kept}") from None
    except BaseException:
        if stage is not None:
            shutil.rmtree(stage, ignore_errors=True)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def file_mode() -> int:
    """The mode of a new file under this process's umask (``0o666 & ~umask``): what a file
    made with ``mkstemp`` (always 0o600) gets before it is renamed into place."""
    return 0o666 & ~_umask()
