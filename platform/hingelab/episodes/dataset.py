"""``Dataset``: a dataset folder as a pandas index, filters and episode iteration.

The index (``index.parquet``, one row per episode) is a cache: it is rebuilt from
the episode files alone whenever the set of ``episodes/*.mcap`` files differs
from its rows (writers never touch it, so concurrent writers need no lock), and
it is replaced atomically. ``.partial`` files (being written, or cut off) are
not episodes and are never indexed; ``hingelab datasets verify`` reports them.

An episode file that cannot be read (corrupt, cut off, foreign, a dangling symlink or a symlink
loop) is handled by the dataset's ``on_corrupt``: ``stop`` (the default) raises one ``DatasetError``
listing every such file of the folder; ``skip`` leaves them out of the index and the iteration and
says on stderr how many it left out. Commands set it for a whole run with ``--on-corrupt`` (``corrupt_policy``).
"""

from __future__ import annotations

import io
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path

import pandas as pd
from tqdm import tqdm

from hingelab.bounded_reads import unreadable_reason
from hingelab.episodes import schemas as S
from hingelab.episodes.card import CARD_FILE, EPISODES_DIR, INDEX_FILE, DatasetCard, atomic_write_bytes, load_card
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.reader import Episode, EpisodeFile, corrupt_error, read_episode, unreadable_error
from hingelab.episodes.writer import PARTIAL_SUFFIX

# Index columns and their dtypes; facts an episode lacks are NA.
INDEX_COLUMNS = {
    "episode_id": "string", "file": "string", "source": "string", "task": "string",
    "object": "string", "seed": "Int64", "attempt": "Int64", "length": "Int64", "return": "float64",
    "success": "boolean", "failure_reason": "string", "config_hash": "string", "recovered": "boolean",
    "schema_version": "Int64", "start_time_s": "float64", "end_time_s": "float64", "bytes": "int64",
    "mtime_ns": "int64",
    # schema v2: which verdict ``success`` is, and ToolShape-v0's secondary one; NA for version-1 files
    "success_verdict": "string", "last_step_success": "boolean",
}


ON_CORRUPT_CHOICES = ("stop", "skip")
_ON_CORRUPT: ContextVar[str] = ContextVar("on_corrupt", default="stop")


@contextmanager
def corrupt_policy(on_corrupt: str):
    """Datasets opened inside take ``on_corrupt`` (``stop`` or ``skip``) unless told otherwise."""
    if on_corrupt not in ON_CORRUPT_CHOICES:
        raise DatasetError(f"on_corrupt must be one of {ON_CORRUPT_CHOICES}, not {on_corrupt!r}")
    token = _ON_CORRUPT.set(on_corrupt)
    try:
        yield
    finally:
        _ON_CORRUPT.reset(token)


def episode_row(path: Path) -> dict:
    """One index row from an episode file's ``episode`` metadata record (no message is read)."""
    try:
        with EpisodeFile(path) as episode_file:
            meta = episode_file.metadata()
    except DatasetError:
        raise
    except Exception as exc:  # noqa: BLE001 - an undecodable record is a corrupt file
        raise corrupt_error(path, exc) from exc
    stat = path.stat()
    row = {name: meta.get(name) for name in INDEX_COLUMNS}
    row.update(file=path.name, bytes=stat.st_size, mtime_ns=stat.st_mtime_ns,
               episode_id=meta.get(S.KEY_EPISODE_ID, path.stem), recovered=meta.get(S.KEY_TRUNCATED_FILE, False))
    return row


def _frame(rows: list[dict]) -> pd.DataFrame:
    frame = pd.DataFrame(rows, columns=list(INDEX_COLUMNS))
    return frame.astype(INDEX_COLUMNS).sort_values("file", ignore_index=True)


class Dataset:
    """A dataset folder: ``card``, ``index`` (DataFrame), ``filter``, iteration, ``read``.

    ``Dataset(root)`` checks the card; ``Dataset(root).index`` reads or rebuilds the index.
    """

    def __init__(self, root, _index: pd.DataFrame | None = None, on_corrupt: str | None = None):
        self.root = Path(root)
        self.card: DatasetCard = load_card(self.root)
        self.episodes_dir = self.root / EPISODES_DIR
        self._index = _index
        self.on_corrupt = on_corrupt or _ON_CORRUPT.get()
        if self.on_corrupt not in ON_CORRUPT_CHOICES:
            raise DatasetError(f"on_corrupt must be one of {ON_CORRUPT_CHOICES}, not {self.on_corrupt!r}")
        self.skipped: list[Path] = []  # files left out as corrupt (on_corrupt="skip")

    def __repr__(self) -> str:
        return f"Dataset({str(self.root)!r}, {len(self)} episodes, source={self.card.source!r})"

    # --- the index ------------------------------------------------------------------------
    def episode_files(self) -> list[Path]:
        """Finished episode files, sorted by name."""
        if not self.episodes_dir.is_dir():
            raise DatasetError(f"{self.episodes_dir} is missing; a dataset keeps its episodes there")
        return sorted(self.episodes_dir.glob("*.mcap"))

    def partial_files(self) -> list[Path]:
        return sorted(self.episodes_dir.glob("*" + PARTIAL_SUFFIX))

    @property
    def index(self) -> pd.DataFrame:
        """One row per episode (columns ``INDEX_COLUMNS``), fresh with respect to the files."""
        if self._index is None:
            self._index = self.build_index()
        return self._index

    def build_index(self, rebuild: bool = False, progress: bool = False) -> pd.DataFrame:
        """Read ``index.parquet`` and bring it up to date with the files; ``rebuild`` ignores it.

        Rows are reused for files whose size and mtime are unchanged, so an index of
        thousands of episodes is refreshed by reading only the new files' metadata.
        """
        files = self.episode_files()
        cached: dict[str, dict] = {}
        index_path = self.root / INDEX_FILE
        if index_path.exists() and not rebuild:
            try:
                old = pd.read_parquet(index_path)
                # an index written before a column existed is rebuilt: its rows lack the new facts
                if set(INDEX_COLUMNS) <= set(old.columns):
                    cached = {row["file"]: row for row in old.to_dict("records")}
            except (OSError, ValueError):  # unreadable cache: rebuild from the files
                cached = {}
        rows, changed, bad = [], len(cached) != len(files), []
        for path in tqdm(files, desc=f"index {self.root.name}", unit="episode", disable=not progress):
            reason = unreadable_reason(path)  # a dangling symlink or a loop: reported like a corrupt file
            if reason is not None:
                bad.append((path, unreadable_error(path, reason)))
                continue
            stat = path.stat()
            row = cached.get(path.name)
            if row is None or row["bytes"] != stat.st_size or row["mtime_ns"] != stat.st_mtime_ns:
                try:
                    row, changed = episode_row(path), True
                except DatasetError as exc:
                    bad.append((path, exc))
                    continue
            rows.append(row)
        if bad and self.on_corrupt == "stop":  # name every bad file at once: those whose chunks fail too
            readable = [self.episodes_dir / row["file"] for row in rows]
            bad += _unreadable(readable, None)
        self._handle_corrupt(bad, len(files))
        frame = _frame(rows)
        if changed or not index_path.exists():
            buffer = io.BytesIO()
            frame.to_parquet(buffer, index=False)
            atomic_write_bytes(index_path, buffer.getvalue())
        return frame

    # --- selection and iteration ---------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.index)

    def filter(self, source: str | None = None, object: str | None = None, success: bool | None = None,
               task: str | None = None, **equal) -> "Dataset":
        """A view with the episodes matching every given fact (``equal``: any index column)."""
        frame = self.index
        mask = pd.Series(True, index=frame.index)
        for column, value in dict(source=source, object=object, success=success, task=task, **equal).items():
            if value is None:
                continue
            if column not in frame.columns:
                raise DatasetError(f"cannot filter {self.root} by {column!r}; index columns: "
                                   + ", ".join(frame.columns))
            mask &= (frame[column] == value).fillna(False)
        return Dataset(self.root, _index=frame[mask].reset_index(drop=True), on_corrupt=self.on_corrupt)

    def paths(self) -> list[Path]:
        return [self.episodes_dir / name for name in self.index["file"]]

    def read(self, i: int, topics=None) -> Episode:
        """The i-th episode of this (filtered) dataset."""
        return read_episode(self.paths()[i], topics=topics)

    def iter_episodes(self, topics=None, progress: bool = False) -> Iterator[Episode]:
        """Each episode, read and validated; a file that cannot be read is handled by ``on_corrupt``."""
        paths, bad = self.paths(), []
        for k, path in enumerate(tqdm(paths, desc=f"read {self.root.name}", unit="episode", disable=not progress)):
            try:
                episode = read_episode(path, topics=topics)
            except DatasetError as exc:
                if self.on_corrupt == "stop":  # name every bad file at once, not one per attempt
                    self._handle_corrupt([(path, exc), *_unreadable(paths[k + 1:], topics)], len(paths))
                bad.append((path, exc))
                continue
            yield episode
        self._handle_corrupt(bad, len(paths))

    def read_checked(self, path: Path, topics=None) -> Episode | None:
        """``read_episode(path)`` of one of this dataset's files under ``on_corrupt``: None if skipped."""
        try:
            return read_episode(path, topics=topics)
        except DatasetError as exc:
            paths = self.paths()
            if self.on_corrupt == "stop":
                self._handle_corrupt([(path, exc), *_unreadable([p for p in paths if p != path], topics)], len(paths))
            self._handle_corrupt([(path, exc)], len(paths))
            return None

    def _handle_corrupt(self, bad: list, total: int) -> None:
        if not bad:
            return
        names = ", ".join(p.name for p, _ in bad[:5]) + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
        if self.on_corrupt == "stop":
            raise DatasetError(
                f"{self.root}: {len(bad)} of {total} episode files cannot be read ({names}); the first: {bad[0][1]} "
                f"-- list them with `hingelab datasets verify {self.root}`, then restore, salvage "
                "(`hingelab datasets recover`) or move them out of episodes/, or pass --on-corrupt skip to leave "
                "them out")
        new = [p for p, _ in bad if p not in self.skipped]
        self.skipped.extend(new)
        if new:
            print(f"hingelab: warning: {self.root}: left out {len(new)} of {total} episode files that cannot be "
                  f"read (--on-corrupt skip): {names}; `hingelab datasets verify {self.root}` says why",
                  file=sys.stderr)

    def __iter__(self) -> Iterator[Episode]:
        return self.iter_episodes()

    def summary(self) -> dict:
        """Counts for ``hingelab datasets info``: episodes, steps, success rate per source/object."""
        frame = self.index
        return {
            "episodes": len(frame),
            "steps": int(frame["length"].fillna(0).sum()),
            "success_rate": float(frame["success"].astype("float64").mean()) if len(frame) else float("nan"),
            "bytes": int(frame["bytes"].sum()),
            "partial_files": len(self.partial_files()),
        }


def _unreadable(paths: list[Path], topics) -> list:
    bad = []
    for path in paths:
        try:
            read_episode(path, topics=topics)
        except DatasetError as exc:
            bad.append((path, exc))
    return bad


def open_dataset(root, on_corrupt: str | None = None) -> Dataset:
    """Open a dataset folder; a folder without ``dataset.json`` is a DatasetError naming it."""
    root = Path(root)
    if not (root / CARD_FILE).exists() and root.is_dir() and not any(root.iterdir()):
        raise DatasetError(f"{root} is an empty folder, not a dataset; generate one into it first "
                           "(hingelab generate ...) or give the path of an existing dataset")
    return Dataset(root, on_corrupt=on_corrupt)


__all__ = ["Dataset", "ON_CORRUPT_CHOICES", "corrupt_policy", "open_dataset", "episode_row", "INDEX_COLUMNS"]
