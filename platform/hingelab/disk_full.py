"""A full disk during a run: one line that names the folder, the free space and what was kept."""

from __future__ import annotations

import errno
import shutil
from pathlib import Path

from hingelab.errors import DiskFullError

DISK_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})


def is_disk_full(exc: BaseException) -> bool:
    return isinstance(exc, OSError) and exc.errno in DISK_FULL_ERRNOS


def disk_full_error(folder, kept: int, requested: int, resume_command: str) -> DiskFullError:
    """The error to raise (from the OSError) when ``folder``'s disk filled up after ``kept`` episodes."""
    folder = Path(folder)
    try:
        free = f"{shutil.disk_usage(folder).free / 1e6:.1f} MB free"
    except OSError:
        free = "free space unknown"
    return DiskFullError(f"the disk holding {folder} is full ({free}): kept the {kept} finished episodes of "
                         f"{requested} (an unfinished one is redone); free some space, "
                         f"then continue with `{resume_command} --resume`")


__all__ = ["DISK_FULL_ERRNOS", "disk_full_error", "is_disk_full"]
