"""``verify``: find every cut-off, corrupt, foreign or schema-less episode file.

A file passes when: it is a file (not a dangling symlink or a symlink loop), it opens as MCAP
with a summary (not cut off), every channel uses the contract's protobuf schema for its topic,
it has an ``episode`` record with the required keys, every chunk passes its CRC, the metadata
records match the CRC32s stored beside the columns (``reader``), every message decodes, the
``/step`` messages match ``length`` (one per step, the reset's record aside), and its
``episode_id`` is a safe file name (``hingelab.safe_names``: exports name folders by it); a
dataset card whose name is not one is reported too. ``.partial`` files are unfinished writes
(a writer still running, or killed): they are reported, and ``recover`` salvages them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mcap.reader import SeekingReader
from tqdm import tqdm

from hingelab.bounded_reads import unreadable_reason
from hingelab.episodes import schemas as S
from hingelab.episodes.card import CARD_FILE, EPISODES_DIR, load_card
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.reader import EpisodeFile, read_episode
from hingelab.episodes.writer import PARTIAL_SUFFIX
from hingelab.safe_names import shown, unsafe_name_reason


@dataclass
class Problem:
    path: Path
    kind: str  # "cut-off", "partial", "corrupt", "foreign", "not-mcap", "metadata", "unexpected", "unsafe-name",
    # "unreadable"
    message: str

    def __str__(self) -> str:
        return f"{self.path}: {self.kind}: {self.message}"


def verify_episode(path: Path) -> Problem | None:
    """None if the episode file is sound, else the first problem found. Never raises."""
    path = Path(path)
    try:
        return _verify_episode(path)
    except Exception as exc:  # noqa: BLE001 - verify reports, it does not crash
        return Problem(path, "corrupt", f"{type(exc).__name__}: {exc}; restore it, or salvage with "
                                        f"hingelab datasets recover {path} --out NEWFILE")


def _verify_episode(path: Path) -> Problem | None:
    reason = unreadable_reason(path)
    if reason is not None:
        return Problem(path, "unreadable", f"{reason}; restore what it points to or remove it from episodes/")
    try:
        with EpisodeFile(path) as episode_file:
            meta = episode_file.metadata()
            raw = episode_file.raw_metadata().get(S.METADATA_EPISODE, {})
            missing = [k for k in S.REQUIRED_EPISODE_KEYS if k not in raw]
            if missing:
                return Problem(path, "metadata", f"episode record lacks {', '.join(missing)}; "
                                                  "rewrite it with EpisodeWriter")
        read_episode(path)  # validating: the chunks' CRCs, the metadata records' digests, the layout
    except DatasetError as exc:
        text = str(exc)
        kind = "cut-off" if "cut off" in text else "foreign" if "foreign schema" in text else (
            "not-mcap" if "not a valid MCAP" in text else "corrupt" if "is corrupt" in text else "metadata")
        if text.startswith(str(path)):
            text = text[len(str(path)):].lstrip(": ")
        if text.startswith("is corrupt ("):  # "corrupt: is corrupt (X); ..." reads twice
            text = text[len("is corrupt ("):].replace(");", ";", 1)
        return Problem(path, kind, text)
    except Exception as exc:  # noqa: BLE001 - e.g. an undecodable metadata record
        return Problem(path, "corrupt", f"{type(exc).__name__}: {exc}; restore it, or salvage with "
                                        f"hingelab datasets recover {path} --out NEWFILE")
    indices = []  # of the /step messages without final
    try:
        with open(path, "rb") as stream:
            reader = SeekingReader(stream, validate_crcs=True)
            for _, channel, message in reader.iter_messages(log_time_order=False):
                decoded = S.TOPIC_TYPES[channel.topic].FromString(message.data)
                if channel.topic == S.TOPIC_STEP and not decoded.final:
                    indices.append(decoded.index)
    except Exception as exc:  # noqa: BLE001 - any failure to read a message is corruption
        return Problem(path, "corrupt", f"{type(exc).__name__}: {exc}; restore it, or salvage with "
                                        f"hingelab datasets recover {path} --out NEWFILE")
    version = int(meta.get(S.KEY_SCHEMA_VERSION) or 1)
    if S.KEY_LENGTH in meta and indices and not _steps_match(sorted(indices), int(meta[S.KEY_LENGTH]), version):
        return Problem(path, "corrupt", f"/step messages {indices[0]}..{indices[-1]} ({len(indices)} of them) do "
                                        f"not match length={meta[S.KEY_LENGTH]}")
    episode_id = meta.get(S.KEY_EPISODE_ID)
    unsafe = None if episode_id is None else unsafe_name_reason(str(episode_id))
    if unsafe is not None:  # sound, but a fact no path may be built from
        return Problem(path, "unsafe-name", f"episode_id {shown(str(episode_id))} {unsafe}; exports "
                                             "name a folder by it, so they refuse this file: rewrite it with "
                                             "EpisodeWriter or move it out of episodes/")
    return None


def _steps_match(indices: list[int], length: int, schema_version: int = 2) -> bool:
    """Whether the /step indices are those of ``length`` steps: indices 0..length-1, or 1..length
    when the first record is an env recording's reset (no transition, so no /step message).
    Version-1 files counted that reset record in ``length`` (1..length-1); a recovered file of any
    version counts the steps it salvaged."""
    accepted = [list(range(length)), list(range(1, length + 1))]
    if schema_version < 2:
        accepted.append(list(range(1, length)))
    return indices in accepted


def verify_dataset(root, progress: bool = False) -> tuple[list[Path], list[Problem]]:
    """(sound episode files, problems) of a dataset folder."""
    root = Path(root)
    name = load_card(root).name
    episodes_dir = root / EPISODES_DIR
    if not episodes_dir.is_dir():
        raise DatasetError(f"{episodes_dir} is missing; a dataset keeps its episodes there")
    good, problems = [], []
    unsafe = unsafe_name_reason(name)
    if unsafe is not None:  # the card's name is a default file name (hingelab view) and the Minari id
        problems.append(Problem(root / CARD_FILE, "unsafe-name", f"the dataset's name {shown(name)} {unsafe}; "
                                                                  "rewrite the name in dataset.json"))
    for path in tqdm(sorted(episodes_dir.iterdir()), desc=f"verify {root.name}", unit="file",
                     disable=not progress):
        if path.name.startswith("."):
            continue  # hidden temporaries of atomic writes (index, card)
        if path.name.endswith(PARTIAL_SUFFIX):
            problems.append(Problem(path, "partial", "unfinished write (writer running or killed); "
                                                     f"salvage with hingelab datasets recover {path} --out NEWFILE"))
        elif path.suffix != ".mcap":
            problems.append(Problem(path, "unexpected", "not an episode file (*.mcap); move it out of episodes/"))
        else:
            problem = verify_episode(path)
            (problems.append(problem) if problem else good.append(path))
    return good, problems


__all__ = ["Problem", "verify_episode", "verify_dataset"]
