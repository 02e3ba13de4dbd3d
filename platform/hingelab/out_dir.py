"""One check of every command's output path, before anything runs: ``check_out`` and ``check_out_file``.

The rule, the same for every command that writes:

* ``--out`` names a folder (``check_out``). An existing file there, a path under one, or a place this process
  cannot create a folder in (a read-only disk, ``/proc``) is one line (``ConfigError``), and nothing is
  written. Writability is probed by creating and removing a hidden folder in the nearest existing parent.
* A folder that exists and holds something (hidden entries such as the writer lock aside) must be the
  command's own kind of output (``OutKind``): a dataset (``dataset.json`` or ``episodes/``), a run
  (``config.json`` or ``run.json``), a sweep (``sweep.toml``), a reproduction (``reproduce.json``), a pick-table
  evaluation (``picks.json``), a report
  (top-level files are tables, figures, text or recordings; sub-folders are other reports), a Minari datasets
  folder (folders only). Anything else, another kind's folder included, is one line naming what is there, and
  nothing is written. What a command then does with its own kind is its policy: a dataset, sweep or
  reproduction is continued only with ``--resume``; a run is continued with ``--resume`` (a start that failed
  before its first step is started again); a report rewrites its files; a ros2 or LeRobot export wants a new
  folder (``OutKind.NEW``).
* A file output (``view --save``, ``train encoder --out``, ``compose low --out``) is ``check_out_file``: not a
  folder, and its parent can be written.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
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


# what a report folder's top-level files may be: the tables, figures, text and recordings commands write
REPORT_SUFFIXES = frozenset({".md", ".csv", ".json", ".html", ".png", ".svg", ".txt", ".rrd", ".toml"})


@dataclass(frozen=True)
class OutKind:
    """A kind of output folder and the entries that mark a folder as one (the names are the writers' own:
    ``episodes.card.CARD_FILE``, ``training.run_folder.CONFIG_FILE`` ..., checked by a test; kept literal
    here so that the parser, which imports this module, stays light)."""

    name: str
    markers: tuple[str, ...] = ()
    report: bool = False  # own when its top-level files are REPORT_SUFFIXES files
    folders_only: bool = False  # own when it holds folders only (a datasets root)
    new: bool = False  # no existing content is its own: the command wants a new or empty folder


DATASET = OutKind("dataset", ("dataset.json", "episodes"))
RUN = OutKind("run", ("config.json", "run.json"))
SWEEP = OutKind("sweep", ("sweep.toml",))
REPRODUCTION = OutKind("reproduction", ("reproduce.json",))
PICKS = OutKind("pick-table evaluation", ("picks.json",))
REPORT = OutKind("report", report=True)
MINARI_ROOT = OutKind("Minari datasets folder", folders_only=True)
NEW = OutKind("export", new=True)
MARKED = (DATASET, RUN, SWEEP, REPRODUCTION, PICKS)


def _visible(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if not p.name.startswith("."))


def _names(paths: list[Path]) -> str:
    shown = ", ".join(p.name + ("/" if p.is_dir() else "") for p in paths[:3])
    return shown + (f" and {len(paths) - 3} more" if len(paths) > 3 else "")


def _check_own(path: Path, kind: OutKind, flag: str) -> None:
    held = _visible(path)
    if not held:
        return
    names = {p.name for p in held}
    if kind.markers and names & set(kind.markers):
        return
    other = next((k for k in MARKED if k is not kind and names & set(k.markers)), None)
    fix = f"give a new or empty folder for the {kind.name}"
    if other is not None:
        raise ConfigError(f"{flag} {path} holds a {other.name} ({_names([p for p in held if p.name in other.markers])})"
                          f", not a {kind.name}; {fix}")
    if kind.report:
        foreign = [p for p in held if p.is_file() and p.suffix.lower() not in REPORT_SUFFIXES]
    elif kind.folders_only:
        foreign = [p for p in held if not p.is_dir()]
    else:
        foreign = held
    if foreign:
        what = "" if kind.new else f", which is not a {kind.name}"
        raise ConfigError(f"{flag} {path} exists and is not empty: it holds {_names(foreign)}{what}; {fix}")


def check_out(path, kind: OutKind, flag: str = "--out") -> Path:
    """``path`` as an output folder of ``kind``: not a file, creatable or writable, and new, empty or of its
    own kind (see the module doc)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{flag} {path} is a file; give a folder (new, or the {kind.name}'s own to continue it)")
    _check_parent(path, flag, "folder")
    if path.is_dir():
        _check_own(path, kind, flag)
    return path


def check_out_file(path, flag: str = "--out") -> Path:
    """``path`` as an output file: not a folder, and its folder creatable or writable."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{flag} {path} is a folder; give a file name")
    _check_parent(path, flag, "file")
    return path


__all__ = ["check_out", "check_out_file", "OutKind", "DATASET", "RUN", "SWEEP", "REPRODUCTION", "REPORT",
           "MINARI_ROOT", "NEW", "REPORT_SUFFIXES"]
