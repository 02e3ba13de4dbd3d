"""Where an export writes: a folder that appears whole or not at all, and the record of what went in.

A failed export leaves nothing behind: every format writes into a hidden temporary sibling of
its final folder (``atomic_folder``) and renames it into place only when everything is written;
on any exception (or Ctrl-C) the temporary folder, and any parent folder the export made, are
removed.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from hingelab.episodes.errors import DatasetError


@dataclass
class ExportResult:
    """What an export wrote: ``path`` (the new folder), counts, what was skipped and how to load it."""

    format: str
    path: Path
    episodes: int
    frames: int
    skipped: dict[str, list[str]] = field(default_factory=dict)  # reason -> episode file names
    notes: list[str] = field(default_factory=list)
    load: str = ""  # how to open it in its own library

    @property
    def skipped_count(self) -> int:
        return sum(len(files) for files in self.skipped.values())


@contextlib.contextmanager
def atomic_folder(final) -> Iterator[Path]:
    """Yield a temporary folder next to ``final``; rename it to ``final`` when the block succeeds.

    ``final`` must not exist (one line naming it otherwise). On any exception the temporary
    folder is deleted, and so is every missing parent folder this made, so a failed export
    leaves nothing behind.
    """
    final = Path(final)
    if final.exists() or final.is_symlink():
        raise DatasetError(f"{final} exists; export into a new folder (or delete that one first)")
    made = []  # parents this created, outermost first
    for parent in reversed(final.parents):
        if not parent.exists():
            made.append(parent)
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _remove_empty(made)
        raise DatasetError(f"cannot create {final.parent} ({exc.strerror}); choose another --out") from exc
    tmp = None
    try:
        if not final.parent.is_dir():
            raise DatasetError(f"{final.parent} is not a folder; choose another --out")
        tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".partial", dir=final.parent))
        yield tmp
        if final.exists():  # made by someone else while this export ran
            raise DatasetError(f"{final} appeared while exporting; export into a new folder")
        os.rename(tmp, final)
    except BaseException:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        _remove_empty(made)
        raise


def _remove_empty(folders: list[Path]) -> None:
    for folder in reversed(folders):  # innermost first
        with contextlib.suppress(OSError):
            folder.rmdir()


__all__ = ["ExportResult", "atomic_folder"]
