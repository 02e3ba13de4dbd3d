"""One check of every command's output path, before anything runs: ``check_out`` and ``check_out_file``.

The rule, the same for every command that writes:

* ``--out`` names a folder (``check_out``). An existing file there, a path under one, or a place this process
  cannot create a folder in (a read-only disk, ``/proc``) is one line (``ConfigError``), and nothing is
  written. Writability is probed by creating and removing a hidden folder in the nearest existing parent.
* What a command does with an existing non-empty folder is the command's own policy, unchanged here: the
  datasets of ``generate`` and ``eval`` refuse one unless ``--resume`` continues it, ``train`` continues it with
  ``--resume``, ``report`` and ``diagnose`` rewrite their files, ``datasets export`` writes beside
  (``--format minari``: a datasets root) or into a new folder.
* A file output (``view --save``, ``train encoder --out``, ``compose low --out``) is ``check_out_file``: not a
  folder, and its parent can be written.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from hingelab.errors import ConfigError


def _nearest_existing(path: Path) -> Path:
    for candidate in (path, *path.parents):
        if candidate.exists():
            return candidate
    return Path(".")


def _writable_folder(folder: Path) -> bool:
    try:
        tempfile.TemporaryDirectory(dir=folder, prefix=".hingelab-write-check-").cleanup()
    except OSError:
        return False
    return True


def _check_parent(path: Path, flag: str, what: str) -> None:
    parent = _nearest_existing(path.parent if what == "file" else path)
    if not parent.is_dir():
        raise ConfigError(f"{flag} {path}: {parent} is a file, so the {what} cannot be made under it; give a path "
                          "in a folder")
    if not _writable_folder(parent):
        raise ConfigError(f"{flag} {path}: this process cannot write in {parent}; give a path on a writable disk")


def check_out(path, flag: str = "--out") -> Path:
    """``path`` as an output folder: not a file, and creatable or writable (see the module doc)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{flag} {path} is a file; give a folder (new, or the run's own to resume it)")
    _check_parent(path, flag, "folder")
    return path


def check_out_file(path, flag: str = "--out") -> Path:
    """``path`` as an output file: not a folder, and its folder creatable or writable."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{flag} {path} is a folder; give a file name")
    _check_parent(path, flag, "file")
    return path


__all__ = ["check_out", "check_out_file"]
