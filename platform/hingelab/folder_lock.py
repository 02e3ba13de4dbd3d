"""One writer per folder: the advisory lock that every command writing a dataset, run or sweep folder holds.

``folder_lock(folder, command)`` takes an exclusive ``flock`` on ``folder/.hingelab.lock`` for the
duration of a ``with`` block and writes the holder into it (PID, host, command line, start time). A
second writer is refused at once with ``FolderBusyError``, one line naming the holder; ``--resume``
is a writer like any other. The kernel drops a flock when its process dies however it dies, so the
lock file a killed command leaves behind is stale but not held: the next writer takes it and
rewrites the holder. A finished command removes the lock file (and the folder, if the lock made
it and nothing else was put there: a refused input leaves no folder behind).

Readers (``datasets info``, ``report``, ``view``) take no lock. A folder's own emptiness checks ("new or
empty --out") ignore the lock file: ``is_empty``. Nested folders have locks of their own: a sweep's
driver holds the sweep folder's, each trial's ``train`` its run folder's; a reproduction holds its
folder's, each stage's command its stage folder's.

The lock is advisory: it binds hingelab's commands, not other programs. On shared storage (a Ray
cluster's NFS) it holds across nodes where the file system supports flock (NFSv4 does).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import shlex
import socket
import sys
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

from hingelab.errors import ConfigError, FolderBusyError

LOCK_FILE = ".hingelab.lock"


def command_line(argv: Sequence[str] | None = None) -> str:
    """``hingelab ARGS`` for a command's arguments; without them, this process's own command line."""
    if argv is not None:
        return "hingelab " + shlex.join(list(argv))
    return shlex.join([Path(sys.argv[0]).name if sys.argv else "python", *sys.argv[1:]])


def _holder_text(fd: int) -> str:
    """The holder a lock file names, as one phrase (``pid N on HOST: COMMAND, since TIME``)."""
    try:
        doc = json.loads(os.pread(fd, 65536, 0).decode(errors="replace") or "{}")
    except (OSError, ValueError):
        doc = {}
    if not isinstance(doc, dict) or "pid" not in doc:
        return "a process that has not written its name yet"
    host = f" on {doc['host']}" if doc.get("host") and doc.get("host") != socket.gethostname() else ""
    return f"pid {doc['pid']}{host}: {doc.get('command', '?')}, since {doc.get('started', '?')}"


def _missing_folders(folder: Path) -> list[Path]:
    """``folder`` and its parents that do not exist yet, outermost first."""
    return [p for p in (*reversed(folder.parents), folder) if not p.exists()]


def _refuse(folder: Path, holder: str):
    return FolderBusyError(f"{folder} is being written by another hingelab command ({holder}); wait for it to end "
                           "or stop it, then run this again")


def _acquire(path: Path, folder: Path) -> int:
    """An open descriptor of ``path`` holding its exclusive flock (or ``FolderBusyError``)."""
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                os.close(fd)
                raise
            holder = _holder_text(fd)
            os.close(fd)
            raise _refuse(folder, holder) from None
        # the holder we waited behind may have removed the file as it ended: a lock on that unlinked
        # file guards nothing, so take the one now at ``path``
        try:
            st = os.stat(path)
            mine = os.fstat(fd)
            if (st.st_ino, st.st_dev) == (mine.st_ino, mine.st_dev):
                return fd
        except FileNotFoundError:
            pass
        os.close(fd)


@contextlib.contextmanager
def folder_lock(folder, command: Sequence[str] | str | None = None) -> Iterator[Path]:
    """Hold ``folder``'s writer lock for the block (the folder is made if missing); yields the lock file.

    ``command``: the holder's command (its arguments, as ``main`` has them, or a line); default this
    process's command line. Raises ``FolderBusyError`` when another process holds the lock."""
    folder = Path(folder)
    made = _missing_folders(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise ConfigError(f"{folder} is a file, not a folder; give a folder") from None
    except OSError as exc:
        raise ConfigError(f"cannot create {folder} ({exc.strerror}); give another folder") from None
    path = folder / LOCK_FILE
    fd = _acquire(path, folder)
    line = command if isinstance(command, str) else command_line(command)
    holder = {"pid": os.getpid(), "host": socket.gethostname(), "command": line,
              "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    os.ftruncate(fd, 0)  # a stale holder (a killed command's) is replaced, not appended to
    os.pwrite(fd, (json.dumps(holder) + "\n").encode(), 0)
    try:
        yield path
    finally:
        # unlink while still holding: a waiter that opened this file then sees it is gone and retries
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
        os.close(fd)
        for made_folder in reversed(made):  # innermost first; only those still empty
            with contextlib.suppress(OSError):
                made_folder.rmdir()


def holder(folder) -> str | None:
    """Who holds ``folder``'s writer lock now (the phrase of ``FolderBusyError``), or None if nobody does."""
    path = Path(folder) / LOCK_FILE
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except FileNotFoundError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise
            return _holder_text(fd)
        return None
    finally:
        os.close(fd)


def refuse_if_locked(folder) -> None:
    """``FolderBusyError`` if a command holds ``folder``'s writer lock (before deleting or reusing it)."""
    busy = holder(folder)
    if busy is not None:
        raise _refuse(Path(folder), busy)


def entries(folder) -> list[Path]:
    """What ``folder`` holds, its lock file left out."""
    folder = Path(folder)
    return [p for p in folder.iterdir() if p.name != LOCK_FILE] if folder.is_dir() else []


def is_empty(folder) -> bool:
    """Whether ``folder`` is missing or holds nothing but its lock file (a new or empty ``--out``)."""
    folder = Path(folder)
    return not folder.exists() or (folder.is_dir() and not entries(folder))


__all__ = ["LOCK_FILE", "folder_lock", "holder", "refuse_if_locked", "is_empty", "entries", "command_line"]
