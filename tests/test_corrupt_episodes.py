"""Corrupt episode files are never read silently and never crash a reader: a seeded fuzz of real
episodes (bit flips, truncation, a zeroed block, a huge length field). Every read either equals
the original's or raises the project's DatasetError; verify never raises and passes only files
that read as the original; no read takes long or allocates much."""

from __future__ import annotations

import struct
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from hingelab.episodes import read_episode
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.verify import verify_episode

KINDS = ("bit flip", "bit flips", "truncation", "zeroed block", "huge length")
PER_KIND = 60  # 300 mutations
MAX_READ_S = 10.0  # a hang, not a speed target (bench datasets measures speed)
MAX_READ_BYTES = 64 << 20  # the episodes are ~100 KB; a hostile length must not allocate gigabytes


@pytest.fixture(scope="module")
def originals(random_pick_dataset) -> list[Path]:
    """Two real ToolPick-v0 episodes (clouds, columns, metadata) recorded by RecordingWrapper."""
    root = random_pick_dataset("fuzz", object="cube", episodes=2, max_episode_steps=25)
    return sorted((root / "episodes").glob("*.mcap"))


def _record_starts(data: bytes) -> list[int]:
    """Offsets of the top-level MCAP records (opcode u8, length u64, body) after the magic."""
    starts, pos = [], 8
    while pos + 9 <= len(data) - 8:
        starts.append(pos)
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        pos += 9 + length
    return starts


def mutate(data: bytes, kind: str, rng: np.random.Generator) -> bytes:
    out = bytearray(data)
    if kind == "bit flip":
        i = int(rng.integers(len(out)))
        out[i] ^= 1 << int(rng.integers(8))
    elif kind == "bit flips":
        for i in rng.integers(len(out), size=int(rng.integers(2, 9))):
            out[int(i)] ^= 1 << int(rng.integers(8))
    elif kind == "truncation":
        out = out[:int(rng.integers(1, len(out)))]
    elif kind == "zeroed block":
        i = int(rng.integers(len(out) - 256))
        out[i:i + 256] = bytes(256)
    elif kind == "huge length":
        start = int(rng.choice(_record_starts(data)))
        out[start + 1:start + 9] = struct.pack("<Q", int(rng.integers(1 << 40, 1 << 62)))
    return bytes(out)


def _same(a, b) -> bool:
    if a.metadata != b.metadata or a.topics.keys() != b.topics.keys() or a.final.keys() != b.final.keys():
        return False
    for topic, fields in a.topics.items():
        if fields.keys() != b.topics[topic].keys():
            return False
        if not all(np.array_equal(v, b.topics[topic][k], equal_nan=v.dtype.kind == "f") for k, v in fields.items()):
            return False
    return all(np.array_equal(v, b.final[k], equal_nan=np.asarray(v).dtype.kind == "f") for k, v in a.final.items())


def test_every_mutation_reads_as_the_original_or_raises_the_dataset_error(originals, tmp_path):
    rng = np.random.default_rng(27)
    truth = {p: read_episode(p) for p in originals}
    outcomes = {kind: {"equal": 0, "dataset error": 0} for kind in KINDS}
    for kind in KINDS:
        for k in range(PER_KIND):
            source = originals[k % len(originals)]
            path = tmp_path / "episodes" / f"{kind.replace(' ', '_')}_{k}.mcap"
            path.parent.mkdir(exist_ok=True)
            path.write_bytes(mutate(source.read_bytes(), kind, rng))
            tracemalloc.start()
            started = time.perf_counter()
            try:
                episode = read_episode(path)
            except DatasetError as exc:
                outcome = "dataset error"
                message = str(exc)
                assert "\n" not in message and str(path) in message, message
            else:
                outcome = "equal"
                assert _same(episode, truth[source]), f"{kind} #{k}: read silently differs from the original"
            seconds = time.perf_counter() - started
            _, peak = tracemalloc.get_traced_memory()
            tracemalloc.stop()
            assert seconds < MAX_READ_S, f"{kind} #{k}: read took {seconds:.1f} s"
            assert peak < MAX_READ_BYTES, f"{kind} #{k}: read allocated {peak / 2**20:.0f} MiB"
            problem = verify_episode(path)  # never raises
            if problem is None:
                assert outcome == "equal", f"{kind} #{k}: verify passed a file that does not read"
            outcomes[kind][outcome] += 1
            path.unlink()
    for kind in KINDS:  # every kind was caught at least sometimes (the mutations reached the data)
        assert outcomes[kind]["dataset error"] > 0, outcomes
    assert sum(o["dataset error"] for o in outcomes.values()) > 0.8 * len(KINDS) * PER_KIND, outcomes


def test_a_flipped_fact_in_the_metadata_is_caught(originals, tmp_path):
    """MCAP metadata records carry no CRC: the writer's digest beside the columns catches a changed value."""
    from hingelab.episodes import mcap_raw
    from hingelab.episodes import schemas as S

    data = originals[0].read_bytes()
    with open(originals[0], "rb") as stream:
        [(offset, length)] = mcap_raw.read_summary(stream).metadata_offsets[S.METADATA_EPISODE]
    key = data.index(b"object", offset, offset + length)  # the key, then its value (u32 length, text)
    value = key + len(b"object") + 4
    broken = bytearray(data)
    broken[value] ^= 0x20  # 'c' -> 'C' (cube): still valid UTF-8, still parses
    path = tmp_path / "episodes" / "flipped.mcap"
    path.parent.mkdir()
    path.write_bytes(bytes(broken))
    with pytest.raises(DatasetError, match="metadata record fails its CRC check"):
        read_episode(path)
    problem = verify_episode(path)
    assert problem is not None and problem.kind == "corrupt"


def test_a_trusted_read_skips_validation(originals):
    fast, checked = read_episode(originals[0], validate=False), read_episode(originals[0])
    assert _same(fast, checked)
