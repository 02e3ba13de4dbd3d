"""The episode table a report counts: the indexes of one or more datasets, one row per episode.

Columns: ``dataset`` (the card's name), ``dataset_path``, the index columns
(``source``, ``object``, ``seed``, ``attempt``, ``length``, ``return``, ``success``,
``failure_reason``, ...; see ``hingelab.episodes.dataset.INDEX_COLUMNS``) and
``object_size`` (metres, float): the episode metadata fact ``object_size`` when a source
records it (through ``EpisodeWriter(extra_metadata={"object_size": ...})``), else NaN.
Reading ``object_size`` opens each file's metadata (no message is read). ``verdict``: what
the episode's ``success`` counts, in words (``schemas.verdict_description``: its
``success_verdict``, or for files written before schema 2 what their task recorded then,
e.g. ToolShape-v0's last step).

Everything comes from the episode files (the index is rebuilt from them when stale),
so a report can be recomputed at any time.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from hingelab.episodes import EpisodeFile
from hingelab.episodes.dataset import Dataset, open_dataset
from hingelab.episodes.schemas import verdict_description
from hingelab.errors import HingelabError

OBJECT_SIZE_KEY = "object_size"  # metres, written by sources that vary the object size


class ReportInputError(HingelabError):
    """A dataset or run folder a report cannot count (missing, empty, no outcomes)."""


def object_sizes(dataset: Dataset) -> np.ndarray:
    """(n_episodes,) float64 metres: each episode's ``object_size`` fact, NaN where absent."""
    sizes = np.full(len(dataset), np.nan)
    for i, path in enumerate(dataset.paths()):
        with EpisodeFile(path) as episode_file:
            value = episode_file.raw_metadata().get("episode", {}).get(OBJECT_SIZE_KEY)
        if value not in (None, ""):
            try:
                sizes[i] = float(value)
            except ValueError:
                pass
    return sizes


def load_dataset_table(root) -> pd.DataFrame:
    """One dataset's episode table (see the module docstring); refuses what cannot be counted."""
    root = Path(root)
    if not root.exists():
        raise ReportInputError(f"{root} does not exist; give a dataset folder (it holds dataset.json)")
    if not root.is_dir():
        raise ReportInputError(f"{root} is a file; give a dataset folder (it holds dataset.json and episodes/)")
    dataset = open_dataset(root)
    index = dataset.index
    if len(index) == 0:
        raise ReportInputError(f"{root} has no episodes in {dataset.episodes_dir}; nothing to report")
    if index["success"].isna().all():
        raise ReportInputError(f"no episode of {root} records 'success' in its metadata; a report counts "
                               "outcomes: rewrite the episodes with EpisodeWriter.set_outcome")
    table = index.copy()
    table.insert(0, "dataset", dataset.card.name)
    table.insert(1, "dataset_path", str(root))
    table[OBJECT_SIZE_KEY] = object_sizes(dataset)
    table["verdict"] = [verdict_description(v, t, s) for v, t, s in
                        zip(table["success_verdict"], table["task"], table["schema_version"])]
    return table


def load_episode_table(roots) -> pd.DataFrame:
    """The episode tables of several datasets, concatenated (rows of unknown success dropped)."""
    roots = list(roots)
    if not roots:
        raise ReportInputError("give at least one dataset folder to report on")
    table = pd.concat([load_dataset_table(root) for root in roots], ignore_index=True)
    table = table[table["success"].notna()].reset_index(drop=True)
    table["success"] = table["success"].astype(bool)
    table["attempt"] = table["attempt"].fillna(1).astype("int64")
    table["object"] = table["object"].fillna("").replace("", "(none)")
    return table


__all__ = ["load_episode_table", "load_dataset_table", "object_sizes", "ReportInputError", "OBJECT_SIZE_KEY"]
