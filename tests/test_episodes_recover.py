"""Cut-off files: a writer killed with SIGKILL, verify naming the partial, recover salvaging it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from hingelab.episodes import DatasetError, create_dataset, read_episode
from hingelab.episodes import schemas as S
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.recover import recover_episode
from hingelab.episodes.synthetic import synthetic_step, write_synthetic_episode
from hingelab.episodes.verify import verify_dataset

WRITER_SCRIPT = textwrap.dedent("""
    import sys, time
    import numpy as np
    from hingelab.episodes.synthetic import synthetic_step
    from hingelab.episodes.writer import EpisodeWriter
    root, n_steps, block = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    rng = np.random.default_rng(11)
    with EpisodeWriter(root, source="killed", seed=11, flush_every_steps=block) as writer:
        print("partial", writer.partial_path, flush=True)
        for k in range(n_steps):
            writer.write_step(k * 0.05, **synthetic_step(rng, k, n_steps))
            if (k + 1) % block == 0:
                print("flushed", k + 1, flush=True)  # that block is in the file now
                time.sleep(0.02)
""")


@pytest.fixture
def dataset(tmp_path):
    create_dataset(tmp_path / "ds", name="test", source="synthetic", config={}, seed=0)
    return tmp_path / "ds"


def test_sigkill_mid_episode_leaves_a_recoverable_partial(dataset, tmp_path):
    n_steps, block = 1000, 10
    proc = subprocess.Popen([sys.executable, "-c", WRITER_SCRIPT, str(dataset), str(n_steps), str(block)],
                            stdout=subprocess.PIPE, text=True)
    partial = None
    flushed = 0
    for line in proc.stdout:
        word, value = line.split()
        if word == "partial":
            partial = value
        else:
            flushed = int(value)
        if flushed >= 60:
            break
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL and partial is not None

    # nothing under a final name; the index has no episode; verify names the partial file
    episodes = dataset / "episodes"
    assert list(episodes.glob("*.mcap")) == []
    assert [p.name for p in episodes.iterdir()] == [os.path.basename(partial)]
    assert len(Dataset(dataset).index) == 0
    good, problems = verify_dataset(dataset)
    assert good == [] and [(p.path.name, p.kind) for p in problems] == [(os.path.basename(partial), "partial")]
    with pytest.raises(DatasetError, match="cut off"):
        read_episode(partial)

    # recover: every complete step before the cut, bit-exact, marked
    result = recover_episode(partial, tmp_path / "recovered.mcap")
    assert result["cut_off"] and result["steps"] >= flushed
    episode = read_episode(result["out"])
    n = episode.length
    assert n == result["steps"] and n < n_steps
    rng = np.random.default_rng(11)
    steps = [synthetic_step(rng, k, n_steps) for k in range(n)]
    np.testing.assert_array_equal(episode.points, np.stack([s["points_hand"] for s in steps]))
    np.testing.assert_array_equal(episode[S.TOPIC_STEP]["observation"],
                                  np.stack([s["transition"]["observation"] for s in steps]))
    np.testing.assert_array_equal(episode[S.TOPIC_PRIVILEGED]["hinge_angle"],
                                  [s["privileged"]["hinge_angle"] for s in steps])
    meta = episode.metadata
    assert meta["recovered"] is True and meta["success"] is False and meta["source"] == "killed"
    assert "cut off" in meta["failure_reason"] and meta["seed"] == 11
    # the recovered file is a sound episode: put it in a dataset and verify it
    os.replace(result["out"], episodes / "recovered.mcap")
    os.remove(partial)
    good, problems = verify_dataset(dataset)
    assert [p.name for p in good] == ["recovered.mcap"] and problems == []


@pytest.mark.parametrize("fraction", [0.05, 0.3, 0.62, 0.97])
def test_recover_salvages_every_complete_message_at_any_cut(dataset, tmp_path, fraction):
    """Cutting inside a chunk keeps that chunk's complete messages (zstd streams decode in part)."""
    path, steps = write_synthetic_episode(dataset, seed=2, n_steps=60, flush_every_steps=20)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap.partial"
    cut.write_bytes(data[: int(len(data) * fraction)])
    result = recover_episode(cut, tmp_path / "out.mcap")
    episode = read_episode(result["out"])
    reference = read_episode(path)
    for topic, fields in episode.topics.items():
        count = len(fields["log_time_ns"])
        for name, array in fields.items():
            np.testing.assert_array_equal(array, reference[topic][name][:count], err_msg=f"{topic}:{name}")
    if fraction > 0.9:
        assert episode.length == 60


def test_recover_refuses_non_mcap_and_existing_output(tmp_path):
    bad = tmp_path / "notes.mcap"
    bad.write_text("not an episode")
    with pytest.raises(DatasetError, match="not an MCAP file"):
        recover_episode(bad, tmp_path / "out.mcap")
    with pytest.raises(DatasetError, match="choose a new --out"):
        recover_episode(bad, bad)
