"""Reading a path that may not deserve it: a dangling symlink, a symlink loop, a file far too large.

``unreadable_reason`` says in a few words why a path cannot be read as a file (or a folder):
it never raises, so the dataset index and ``datasets verify`` report such an episode file as
they report a corrupt one. ``resolved_input`` resolves a path a command takes as an input
(``--from``, ``--init-from``) into one line when it cannot. ``check_file_size`` refuses a file
above a limit from its size alone, before a byte of it is read.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from hingelab.errors import ConfigError

# the mesh files of --object mesh:PATH (hingelab.sim.mesh_objects), here so that the parser's --max-mesh-mb
# needs no NumPy (a fast --help)
DEFAULT_MAX_MESH_MB = 200.0  # a mesh file above this is refused before it is read (trimesh holds several copies)
MAX_MESH_MB_ENV = "HINGELAB_MAX_MESH_MB"


class FileTooLargeError(ConfigError):
    """A file above the size a reader accepts (a limit the user can raise), refused before it is read."""


def unreadable_reason(path, want: str = "file") -> str | None:
    """None if ``path`` can be opened as ``want`` (``"file"``, ``"folder"`` or ``"any"``), else why not
    ("is a dangling symlink to X", "is a symlink loop", ...). Never raises."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        if os.path.islink(path):
            try:
                target = os.readlink(path)
            except OSError:
                target = "?"
            return f"is a dangling symlink (to {target}, which does not exist)"
        return "does not exist"
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "is a symlink loop (its links never reach a file)"
        if exc.errno == errno.ENAMETOOLONG:
            return "has a name too long for the file system"
        return f"cannot be read ({exc.strerror or type(exc).__name__})"
    except ValueError as exc:  # an embedded NUL
        return f"is not a usable path ({exc})"
    if want == "file" and not stat.S_ISREG(mode):
        return "is a folder, not a file" if stat.S_ISDIR(mode) else "is not a regular file"
    if want == "folder" and not stat.S_ISDIR(mode):
        return "is a file, not a folder"
    return None


def resolved_input(path, flag: str) -> Path:
    """``path`` made absolute with its symlinks resolved, or a one-line ``ConfigError`` naming ``flag``
    when it cannot be (a symlink loop); a path that does not exist is left to the caller's own check."""
    path = Path(path)
    try:
        return path.resolve()
    except (OSError, RuntimeError) as exc:  # Python < 3.13 raises RuntimeError on a symlink loop
        reason = unreadable_reason(path, "any") or f"cannot be resolved ({exc})"
        raise ConfigError(f"{flag} {path} {reason}; give the path of the folder itself") from None


def check_file_size(path, limit_bytes: int, what: str, fix: str) -> int:
    """The size of the file ``path`` in bytes; a one-line ``HingelabError`` if it is above ``limit_bytes``
    (decided by ``stat`` alone: nothing is read, so a huge or sparse file is refused at once)."""
    size = os.stat(path).st_size
    if size > limit_bytes:
        raise FileTooLargeError(f"{what} {path} is {_size(size)}, above the {_size(limit_bytes)} limit; {fix}")
    return size


def _size(n: int) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} bytes"


__all__ = ["FileTooLargeError", "check_file_size", "resolved_input", "unreadable_reason"]
