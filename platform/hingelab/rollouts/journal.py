"""Resumable evaluations: each finished episode's row, one JSON line, flushed to disk as it finishes.

``hingelab eval low|high --resume`` continues a stopped evaluation (a full disk, a kill) from
``OUT/episodes.partial.jsonl``: the episodes it lists are kept, every other trace of the stopped run
(``.partial`` files, an episode file finished just before the stop but not yet listed) is removed,
and the remaining episodes run with their own seeds, so the folder ends as an uninterrupted run's.
"""

from __future__ import annotations

import json
import os
import shlex
from pathlib import Path

from hingelab.episodes.card import load_card
from hingelab.episodes.dataset import Dataset
from hingelab.errors import ConfigError
from hingelab.folder_lock import is_empty
from hingelab.json_text import finite_or_null
from hingelab.provenance import differing_settings

JOURNAL_FILE = "episodes.partial.jsonl"


def _plain(value):
    return value.tolist() if hasattr(value, "tolist") else str(value)


class EpisodeJournal:
    def __init__(self, folder):
        self.path = Path(folder) / JOURNAL_FILE
        self.rows: list[dict] = []

    def load(self) -> list[dict]:
        """The rows of a stopped run (a torn last line, written as the disk filled, is dropped)."""
        self.rows = []
        if self.path.exists():
            for line in self.path.read_text().splitlines():
                try:
                    self.rows.append(json.loads(line))
                except json.JSONDecodeError:
                    break
        return self.rows

    def append(self, row: dict) -> None:
        with open(self.path, "a") as stream:
            # NaN and infinity as null: JSON has neither, and a journal row must read anywhere
            plain = json.loads(json.dumps(row, default=_plain))
            stream.write(json.dumps(finite_or_null(plain), allow_nan=False) + "\n")
            stream.flush()
            os.fsync(stream.fileno())
        self.rows.append(row)

    def finish(self) -> None:
        self.path.unlink(missing_ok=True)


def prepare_resume(out: Path, config: dict, resume: bool) -> EpisodeJournal:
    """The journal of an evaluation into ``out``: empty for a new folder; with ``resume``, the stopped run's
    (its dataset card must hold the same ``config``), its stray files removed."""

    out = Path(out)
    journal = EpisodeJournal(out)
    if not resume:
        if not is_empty(out):
            raise ConfigError(f"{out} is not empty; evaluate into a new folder, or continue a stopped "
                              "evaluation there with --resume")
        return journal
    if not (out / "dataset.json").exists():
        raise ConfigError(f"--resume: {out} holds no evaluation to continue; leave --resume out to start one")
    differ = differing_settings(load_card(out).config, config)
    if differ:
        raise ConfigError(f"--resume: {out} was evaluated with other settings ("
                          + ", ".join(f"{k} {old!r}, now {new!r}" for k, (old, new) in differ.items())
                          + "); give the same ones, or a new --out")
    if not journal.path.exists() and (out / "episodes.csv").exists():
        raise ConfigError(f"--resume: {out} holds a finished evaluation (episodes.csv, no journal of a stopped "
                          "one); nothing to resume")
    rows = journal.load()
    kept = {int(r["seed"]) for r in rows}
    episodes = out / "episodes"
    for partial in episodes.glob("*.partial"):
        partial.unlink()
    index = Dataset(out).build_index(rebuild=True)
    for name, seed in zip(index["file"], index["seed"]):
        if int(seed) not in kept:  # finished after the journal's last line: redone
            (episodes / name).unlink()
    (out / "index.parquet").unlink(missing_ok=True)
    return journal


def command_line(argv: list[str] | None) -> str:
    """The command that ran, ``--resume`` left out (``disk_full_error`` adds it)."""

    return "hingelab " + shlex.join([a for a in (argv or []) if a != "--resume"])


__all__ = ["EpisodeJournal", "JOURNAL_FILE", "command_line", "prepare_resume"]
