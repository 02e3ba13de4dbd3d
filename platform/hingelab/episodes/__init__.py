"""Episode datasets: one MCAP file per rollout, the contract every learner, viewer and report reads.

The public API (see datasets/README.md for the file contract):

- ``create_dataset(root, name, source, config, seed)`` -> the card ``dataset.json``
- ``EpisodeWriter(root, source=..., ...)`` -> context manager, ``write_step(t, ...)``
- ``read_episode(path)`` -> ``Episode`` (numpy arrays per topic)
- ``Dataset(root)``: index (pandas), ``filter``, iteration, transitions
"""

from hingelab.episodes.card import DatasetCard, config_hash, create_dataset, load_card
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.reader import Episode, EpisodeFile, read_episode
from hingelab.episodes.writer import EpisodeWriter

__all__ = [
    "DatasetCard", "DatasetError", "Episode", "EpisodeFile", "EpisodeWriter", "config_hash",
    "create_dataset", "load_card", "read_episode",
]
