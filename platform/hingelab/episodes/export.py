"""Export a hingelab dataset to the layouts neighbouring libraries load, and import them back.

``export_dataset(dataset, "minari" | "lerobot", out)`` dispatches to one module per format:

- ``export_minari.py``: a Minari 0.5 dataset (``OUT/NAMESPACE/NAME-vN/data/main_data.hdf5`` and
  ``metadata.json``) that ``minari.load_dataset("NAMESPACE/NAME-vN")`` opens with
  ``MINARI_DATASETS_PATH=OUT``;
- ``export_lerobot.py``: a LeRobotDataset v3.0 folder (``OUT/meta/info.json``, ``stats.json``,
  ``tasks.parquet``, ``meta/episodes/...``, ``data/chunk-000/file-000.parquet``);
- ``export_source.py``: what both take from an episode (the ``/step`` arrays, the tool clouds
  aligned to the observations by log time, what is skipped and why), and the way back.

A failed export leaves nothing behind: every format writes into a hidden temporary sibling
of its final folder (``atomic_folder``) and renames it into place only when everything is
written; on any exception (or Ctrl-C) the temporary folder, and any parent folder the export
made, are removed.
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

FORMATS = ("minari", "lerobot")


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


def export_dataset(dataset, fmt: str, out, dataset_id: str | None = None, progress: bool = False) -> ExportResult:
    """Export ``dataset`` (a ``Dataset``) as ``fmt`` into ``out`` (see the format modules)."""
    if fmt == "minari":
        return export_minari(dataset, out, dataset_id=dataset_id, progress=progress)
    if dataset_id is not None:
        raise DatasetError("--dataset-id names a Minari dataset; a LeRobot export is the --out folder itself")
    if fmt == "lerobot":
        return export_lerobot(dataset, out, progress=progress)
    raise DatasetError(f"unknown export format {fmt!r}; choose one of {', '.join(FORMATS)}")


# The format modules import ``atomic_folder`` from here, so they are imported when used.
def export_minari(dataset, out, **options) -> ExportResult:
    from hingelab.episodes.export_minari import export_minari as run

    return run(dataset, out, **options)


def export_lerobot(dataset, out, **options) -> ExportResult:
    from hingelab.episodes.export_lerobot import export_lerobot as run

    return run(dataset, out, **options)


def import_minari(path, root, **options) -> Path:
    from hingelab.episodes.export_minari import import_minari as run

    return run(path, root, **options)


def import_lerobot(path, root) -> Path:
    from hingelab.episodes.export_lerobot import import_lerobot as run

    return run(path, root)


__all__ = ["ExportResult", "FORMATS", "atomic_folder", "export_dataset", "export_minari", "export_lerobot",
           "import_minari", "import_lerobot"]
