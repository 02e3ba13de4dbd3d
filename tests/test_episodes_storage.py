"""Storage layout: per-chunk compression, split cloud chunks, parallel reads, old files."""

from __future__ import annotations

import numpy as np
import pytest

from hingelab.episodes import create_dataset, mcap_raw, read_episode
from hingelab.episodes import schemas as S
from hingelab.episodes.reader import EpisodeFile
from hingelab.episodes.recover import recover_episode
from hingelab.episodes.synthetic import write_synthetic_episode
from hingelab.episodes.verify import verify_episode

N_STEPS = 60
MIXED = dict(compression="zstd", cloud_compression="none", cloud_chunk_bytes=64 << 10)


@pytest.fixture
def dataset(tmp_path):
    create_dataset(tmp_path / "ds", name="test", source="synthetic", config={}, seed=0)
    return tmp_path / "ds"


def _chunk_compressions(path) -> dict[str, set]:
    """{"clouds" | "other": set of chunk compression strings} from the summary's chunk indexes."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    cloud_id = next(c.id for c in summary.channels.values() if c.topic == S.TOPIC_POINTS)
    out = {"clouds": set(), "other": set()}
    for index in summary.chunk_indexes:
        kind = "clouds" if set(index.message_index_offsets) == {cloud_id} else "other"
        out[kind].add(index.compression)
    return out


def test_mixed_compression_file_decodes_with_the_plain_mcap_library(dataset):
    """Uncompressed cloud chunks and zstd chunks in one file: mcap + mcap_protobuf read it all."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    path, steps = write_synthetic_episode(dataset, seed=1, n_steps=N_STEPS, **MIXED)
    assert _chunk_compressions(path) == {"clouds": {""}, "other": {"zstd"}}
    clouds, observations = [], []
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            if channel.topic == S.TOPIC_POINTS:
                clouds.append(np.frombuffer(decoded.data, "<f4").reshape(-1, 3))
            elif channel.topic == S.TOPIC_STEP and not decoded.final:
                observations.append(np.asarray(decoded.observation, dtype=np.float32))
    np.testing.assert_array_equal(np.stack(clouds), np.stack([s["points_hand"] for s in steps]))
    np.testing.assert_array_equal(np.stack(observations),
                                  np.stack([s["transition"]["observation"] for s in steps]))
    assert verify_episode(path) is None  # CRCs, schemas, counts: mcap's SeekingReader agrees


@pytest.mark.parametrize("options", [
    {},  # the default
    dict(cloud_chunk_bytes=1 << 30),  # one cloud chunk per block
    dict(cloud_compression="lz4"),
    dict(cloud_compression="none", compression="none"),
    MIXED,
], ids=["default", "one-cloud-chunk", "lz4-clouds", "uncompressed", "mixed"])
@pytest.mark.parametrize("threads", [1, 2])
def test_every_layout_reads_back_bit_exact_fast_and_generic(dataset, options, threads, monkeypatch):
    monkeypatch.setattr(mcap_raw, "READ_THREADS", threads)
    path, steps = write_synthetic_episode(dataset, seed=4, n_steps=N_STEPS, flush_every_steps=25, **options)
    fast, generic = read_episode(path), read_episode(path, generic=True)
    want = np.stack([s["points_hand"] for s in steps])
    np.testing.assert_array_equal(fast.points, want)
    assert fast.points.dtype == np.float32 and fast.points.flags.c_contiguous
    for topic, fields in generic.topics.items():
        for name, array in fields.items():
            np.testing.assert_array_equal(fast[topic][name], array, err_msg=f"{topic}:{name}")
    # the cloud chunks hold only clouds, sequence numbers count the clouds
    with EpisodeFile(path) as episode_file:
        chunks, cloud_only = episode_file.chunks_of(S.TOPIC_POINTS)
    assert cloud_only and len(chunks) >= 3  # 3 blocks of flush_every_steps=25


def test_default_splits_an_episode_of_clouds_into_chunks_for_parallel_reads(dataset):
    path, _ = write_synthetic_episode(dataset, seed=6, n_steps=200)
    with EpisodeFile(path) as episode_file:
        chunks, cloud_only = episode_file.chunks_of(S.TOPIC_POINTS)
    assert cloud_only and len(chunks) == 2  # 600 KiB of points, chunks of at most 320 KiB
    assert _chunk_compressions(path) == {"clouds": {"zstd"}, "other": {"zstd"}}


@pytest.mark.parametrize("fraction", [0.1, 0.45, 0.8, 0.97])
def test_recover_cut_off_file_with_mixed_chunks(dataset, tmp_path, fraction):
    """A cut through uncompressed cloud chunks or zstd chunks keeps every complete message."""
    path, steps = write_synthetic_episode(dataset, seed=2, n_steps=N_STEPS, flush_every_steps=20, **MIXED)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap.partial"
    cut.write_bytes(data[: int(len(data) * fraction)])
    result = recover_episode(cut, tmp_path / "out.mcap")
    episode, reference = read_episode(result["out"]), read_episode(path)
    for topic, fields in episode.topics.items():
        count = len(fields["log_time_ns"])
        for name, array in fields.items():
            np.testing.assert_array_equal(array, reference[topic][name][:count], err_msg=f"{topic}:{name}")
    assert result["cut_off"] and episode.metadata["recovered"] is True
    if fraction > 0.9:
        assert episode.length == N_STEPS


def test_file_from_the_mcap_library_writer_still_reads(dataset, tmp_path):
    """Files written before ChunkWriter (mcap's Writer, one cloud chunk per block) read the same."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    path, steps = write_synthetic_episode(dataset, seed=3, n_steps=N_STEPS, **MIXED)
    old = tmp_path / "old.mcap"
    with open(path, "rb") as f, open(old, "wb") as out:
        reader = make_reader(f)
        summary = reader.get_summary()
        writer = Writer(out, chunk_size=1 << 40, compression=CompressionType.ZSTD)
        writer.start()
        schema_ids = {i: writer.register_schema(s.name, s.encoding, s.data) for i, s in summary.schemas.items()}
        channel_ids = {i: writer.register_channel(c.topic, c.message_encoding, schema_ids[c.schema_id], c.metadata)
                       for i, c in summary.channels.items()}
        messages = list(reader.iter_messages(log_time_order=False))
        for is_cloud in (True, False):
            for _, channel, message in messages:
                if (channel.topic == S.TOPIC_POINTS) == is_cloud:
                    writer.add_message(channel_ids[channel.id], message.log_time, message.data,
                                       message.publish_time, message.sequence)
            writer.flush()
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, record.metadata)
        writer.finish()
    np.testing.assert_array_equal(read_episode(old).points, read_episode(path).points)
    np.testing.assert_array_equal(read_episode(old)[S.TOPIC_STEP]["observation"],
                                  read_episode(path)[S.TOPIC_STEP]["observation"])


def test_bad_compression_is_refused(dataset):
    from hingelab.episodes import EpisodeWriter

    with pytest.raises(ValueError, match="cloud_compression must be one of"):
        EpisodeWriter(dataset, source="x", cloud_compression="brotli")
