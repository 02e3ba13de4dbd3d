"""The dataset card ``dataset.json``: what produced a dataset.

Fields: ``name``, ``source``, ``config`` (the producing config, a JSON object),
``config_hash`` (sha256 of its canonical JSON, first 16 hex digits),
``hingelab_version``, ``git_commit``, ``seed``, ``created`` (UTC, ISO 8601),
``schema_version``, ``description``.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import tempfile
from dataclasses import asdict, dataclass, field
from pathlib import Path

from hingelab.episodes import schemas as S
from hingelab.episodes.errors import DatasetError
from hingelab.json_text import strict_dumps
from hingelab.provenance import code_version

CARD_FILE = "dataset.json"
EPISODES_DIR = "episodes"
INDEX_FILE = "index.parquet"


def config_hash(config: dict) -> str:
    """Stable hash of a config: sha256 of sorted-key JSON, 16 hex digits."""
    text = json.dumps(config, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass
class DatasetCard:
    name: str
    source: str
    config: dict = field(default_factory=dict)
    config_hash: str = ""
    seed: int | None = None
    description: str = ""
    hingelab_version: str = ""
    git_commit: str = ""
    created: str = ""
    schema_version: int = S.SCHEMA_VERSION

    def to_json(self) -> str:
        return strict_dumps(asdict(self), "dataset.json", indent=2, sort_keys=False, default=str) + "\n"


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write a file under a temporary name, fsync, then rename over ``path``."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def create_dataset(root, name: str, source: str, config: dict | None = None, seed: int | None = None,
                   description: str = "") -> DatasetCard:
    """Create (or reopen) the dataset folder ``root``: card, ``episodes/``.

    Reopening with the same name, source and config is allowed (several writer
    processes may call this at once); a different config raises, since one
    dataset is the output of one config.
    """
    root = Path(root)
    config = dict(config or {})
    card = DatasetCard(
        name=name, source=source, config=config, config_hash=config_hash(config), seed=seed,
        description=description, created=_dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        **code_version(),
    )
    (root / EPISODES_DIR).mkdir(parents=True, exist_ok=True)
    card_path = root / CARD_FILE
    if card_path.exists():
        existing = load_card(root)
        if (existing.name, existing.source, existing.config_hash) != (name, source, card.config_hash):
            raise DatasetError(
                f"{card_path} already describes dataset {existing.name!r} (source {existing.source!r}, "
                f"config {existing.config_hash}); write into a new folder or delete the old one"
            )
        return existing
    atomic_write_bytes(card_path, card.to_json().encode())
    return card


def load_card(root) -> DatasetCard:
    """Read ``root/dataset.json``; a missing or malformed card is a DatasetError."""
    root = Path(root)
    card_path = root / CARD_FILE
    if not root.is_dir():
        raise DatasetError(f"{root} is not a folder; give the path of a dataset folder (it holds {CARD_FILE})")
    if not card_path.is_file():
        raise DatasetError(
            f"{card_path} is missing: {root} is not a hingelab dataset; "
            "create it with hingelab.episodes.create_dataset() or point at the dataset folder"
        )
    try:
        data = json.loads(card_path.read_text())
        known = {k: data[k] for k in DatasetCard.__dataclass_fields__ if k in data}
        return DatasetCard(**known)
    except (ValueError, TypeError) as exc:
        raise DatasetError(f"{card_path} is not a valid dataset card ({exc}); restore or rewrite it") from exc
