"""One writer per output folder: the lock ``mcjax sweep`` and ``mcjax tune`` hold in ``--out``.

Two commands writing one folder at once (two terminals, a cluster job submitted twice) would
each re-run and rewrite the other's chunks and could leave a dataset no one asked for. So a
command that writes a folder first creates ``OUT/.mcjax.lock``, holding the host name, the
process id, the process's start and the command line, in one atomic step (the complete file is
hard-linked into place, which fails when a lock is already there). A second command on the same
folder stops with one line naming the holder (exit code 2). The holder refreshes the file's
modification time every :data:`HEARTBEAT` seconds and removes it on any exit: at the end, on an
error, on Ctrl-C (:data:`mcjax.base.interrupt.AT_EXIT`).

A lock left by a process that is gone (``kill -9``, a crashed node) is taken over, with one
warning line naming it: on this host when its process no longer runs (or its process id now
belongs to a process started later); from another host when it has not been refreshed for
:data:`STALE_AFTER` seconds (its host may be down; a live holder refreshes it every minute,
so only a host whose clock or file system stalls for that long could lose its lock). No JAX.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sys
import threading
import time
import uuid
from pathlib import Path
from typing import Callable, Iterator

from mcjax.base import interrupt

#: The lock's file name in an output folder.
LOCK_FILE = ".mcjax.lock"
#: Seconds between the holder's refreshes of the lock file's modification time.
HEARTBEAT = 60.0
#: Seconds without a refresh after which a lock from another host counts as left behind (10 min).
STALE_AFTER = 600.0


class LockError(RuntimeError):
    """Another command holds the output folder; the message, one line, names it."""


def _start_ticks(pid: int) -> str | None:
    """When process ``pid`` started (clock ticks since boot, ``/proc/PID/stat``), or None where
    that cannot be read: tells a process from a later one that reuses its id."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text.rpartition(")")[2].split()
    return fields[19] if len(fields) > 19 else None


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    except (OSError, OverflowError, ValueError):
        return False
    return True


def read_holder(out_dir: str | Path) -> tuple[dict | None, float] | None:
    """The lock of ``out_dir`` (its content, None when unreadable; and its age in seconds since
    the last refresh), or None when there is none."""
    path = Path(out_dir) / LOCK_FILE
    try:
        age = time.time() - path.stat().st_mtime
        info = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError, ValueError):
        return None if not path.exists() else (None, age)
    return (info if isinstance(info, dict) else None), age


def left_behind(info: dict | None, age: float) -> str:
    """Why a lock is left behind by a process that is gone ("" when its holder may still run)."""
    if info is None:
        return "unreadable and not refreshed for a minute" if age > HEARTBEAT else ""
    host, pid = info.get("host"), info.get("pid")
    if host == socket.gethostname() and isinstance(pid, int):
        if not _running(pid):
            return f"process {pid} no longer runs"
        started = _start_ticks(pid)
        if info.get("start") is not None and started is not None and started != info["start"]:
            return f"process id {pid} now belongs to another process"
        return ""
    if age > STALE_AFTER:
        return f"not refreshed for {age / 60:.0f} min (a running command refreshes it every {HEARTBEAT:.0f} s)"
    return ""


def describe(info: dict | None) -> str:
    """The holder of a lock in words: its command, process id, host and start."""
    if info is None:
        return "an unreadable lock"
    since = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(info.get("time", 0)))
    return f"{info.get('command') or 'mcjax'} (pid {info.get('pid')} on {info.get('host')}, started {since})"


class OutputLock:
    """The lock of one output folder, held by this process (:func:`hold`)."""

    def __init__(self, out_dir: str | Path, warn: Callable[[str], None] | None = None):
        self.out_dir = Path(out_dir)
        self.path = self.out_dir / LOCK_FILE
        self.warn = warn or (lambda text: print(f"warning: {text}", file=sys.stderr, flush=True))
        self.token = uuid.uuid4().hex
        self.created_folder = False
        self._stop = threading.Event()
        self._beat: threading.Thread | None = None

    def _content(self) -> bytes:
        info = {"host": socket.gethostname(), "pid": os.getpid(), "start": _start_ticks(os.getpid()),
                "time": time.time(), "command": " ".join(["mcjax", *sys.argv[1:]])[:300], "token": self.token}
        return json.dumps(info).encode()

    def _place(self) -> bool:
        """Create the lock file whole, atomically; False when there is one already."""
        tmp = self.out_dir / f".{LOCK_FILE}.{os.getpid()}.{self.token[:12]}.tmp"
        tmp.write_bytes(self._content())
        try:
            os.link(tmp, self.path)
            return True
        except FileExistsError:
            return False
        except OSError:  # a file system without hard links: create it exclusively instead
            try:
                fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            except FileExistsError:
                return False
            with os.fdopen(fd, "wb") as fh:
                fh.write(tmp.read_bytes())
            return True
        finally:
            tmp.unlink(missing_ok=True)

    def acquire(self) -> None:
        """Take the lock, or take over one left behind (with a warning); :class:`LockError` when
        another command holds it. On this host the check and the take-over run under an
        ``flock`` of the folder, so two commands cannot both take over one left-behind lock."""
        self.created_folder = not self.out_dir.exists()
        self.out_dir.mkdir(parents=True, exist_ok=True)
        with _folder_flock(self.out_dir):
            for _ in range(5):
                if self._place():
                    break
                held = read_holder(self.out_dir)
                if held is None:
                    continue  # released meanwhile
                why = left_behind(*held)
                if not why:
                    self._forget_folder()
                    raise LockError(f"output folder {self.out_dir} is in use by {describe(held[0])}; wait for it to "
                                    f"end or choose another --out")
                self.warn(f"taking over the lock of {self.out_dir} left by {describe(held[0])}: {why}")
                self.path.unlink(missing_ok=True)
            else:
                raise LockError(f"output folder {self.out_dir}: cannot take its lock {self.path}")
        interrupt.AT_EXIT.append(self.release)
        self._beat = threading.Thread(target=self._heartbeat, name="mcjax-lock", daemon=True)
        self._beat.start()

    def _heartbeat(self) -> None:
        while not self._stop.wait(HEARTBEAT):
            with contextlib.suppress(OSError):
                os.utime(self.path)

    def release(self) -> None:
        """Remove the lock file if it is still this process's (and the folder, if the lock made
        it and it is empty). Safe to call twice, and from another thread."""
        self._stop.set()
        with contextlib.suppress(ValueError):
            interrupt.AT_EXIT.remove(self.release)
        held = read_holder(self.out_dir)
        if held is not None and held[0] is not None and held[0].get("token") == self.token:
            self.path.unlink(missing_ok=True)
        self._forget_folder()

    def _forget_folder(self) -> None:
        if self.created_folder:
            with contextlib.suppress(OSError):
                self.out_dir.rmdir()  # only if empty


@contextlib.contextmanager
def _folder_flock(folder: Path) -> Iterator[None]:
    try:
        import fcntl

        fd = os.open(folder, os.O_RDONLY)
    except (ImportError, OSError):
        yield
        return
    try:
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the flock


@contextlib.contextmanager
def hold(out_dir: str | Path, warn: Callable[[str], None] | None = None) -> Iterator[OutputLock | None]:
    """Hold the lock of ``out_dir`` for the length of the ``with`` block (:class:`OutputLock`);
    :class:`LockError` when another command holds it. Yields None (nothing to lock) when
    ``out_dir`` is a file: the caller says so."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        yield None
        return
    lock = OutputLock(out_dir, warn)
    lock.acquire()
    try:
        yield lock
    finally:
        lock.release()
