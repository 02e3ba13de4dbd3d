"""``hingelab bench datasets``: hingelab MCAP episodes vs h5py and parquet, same episodes.

Each episode: 200 steps of a 256-point float32 cloud, the 26-D float32 state, a 9-D
float32 action and a float64 reward (identical arrays for every format). Measured in
one run, best of ``repeats``:

- write steps/s: the episode's arrays to files (hingelab: one ``EpisodeWriter`` per
  episode, a standard message per step plus the per-episode columns; h5py: one group
  per episode in one file, Minari/robomimic style; parquet: one file per episode,
  LeRobot v2 style, fixed-size lists, dictionaries off);
- read steps/s, everything: clouds + state + action + reward back into numpy;
- read steps/s, transitions: state + action + reward only (what fills a replay buffer);
- bytes per step on disk.

Also shown, not baselines: hingelab's generic path (decode every message with
protobuf), i.e. what a one-message-per-step design costs a learner; the other
storage options of ``EpisodeWriter`` (per-chunk compression: clouds uncompressed or
lz4 with the rest zstd; nothing compressed); the default files read with one thread
(no parallel chunk decompression). ``byte_breakdown`` accounts for every byte per step.

ROS 2 bag import (``ros2_import_rows``): a rig bag written with ``rosbags`` (30 Hz camera cloud,
100 Hz joints and TF, 20 Hz actions, 30 Hz object pose, trial events) into episodes with
``hingelab.ros2.import_bags`` (alignment, the camera cloud pipeline, ToolState, the writer), in bag
messages per second, against a bare ``rosbags`` read of the same bag (AnyReader, every message
deserialized): the ratio is what turning a bag into episodes costs over just reading it. Twice: the
default rig bag's small clouds, and one trial of real-size clouds (an Azure Kinect's whole scene,
200k points at 15 Hz), with the camera frames' share of the import's time.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from rosbags.highlevel import AnyReader
from tqdm import tqdm

from hingelab.bench.table import BenchTable
from hingelab.episodes import mcap_raw
from hingelab.episodes import schemas as S
from hingelab.episodes.card import create_dataset
from hingelab.episodes.reader import EpisodeFile, read_episode
from hingelab.episodes.synthetic import CONTROL_DT_S, tweezer_cloud
from hingelab.episodes.writer import EpisodeWriter
from hingelab.perception.encoder import load_encoder
from hingelab.ros2.bag_import import import_bags
from hingelab.ros2.rig_bag import RigBagSpec, RigTrial, write_rig_bag

# the code this benchmark measures (the bench module itself: hingelab.bench.measured_paths); the ROS 2
# import runs the camera cloud pipeline and ToolState (perception/) on every step
MEASURES = ("platform/hingelab/episodes", "platform/hingelab/ros2", "platform/hingelab/perception",
            "platform/hingelab/camera.py", "assets/checkpoints/encoder.pt")

STEPS_PER_EPISODE = 200


def make_episodes(n_episodes: int, seed: int = 0) -> list[dict[str, np.ndarray]]:
    """Identical inputs for every format: points (T, 256, 3) f32, state (T, 26) f32, action (T, 9) f32,
    reward (T,) f64."""
    rng = np.random.default_rng(seed)
    episodes = []
    for _ in range(n_episodes):
        hinge = 0.175 + 0.15 * np.sin(0.1 * np.arange(STEPS_PER_EPISODE))
        episodes.append({
            "points": np.stack([tweezer_cloud(rng, h) for h in hinge]),
            "state": rng.normal(0, 1, (STEPS_PER_EPISODE, 26)).astype(np.float32),
            "action": rng.uniform(-0.05, 0.05, (STEPS_PER_EPISODE, 9)).astype(np.float32),
            "reward": rng.normal(0, 1, STEPS_PER_EPISODE),
        })
    return episodes


# --- hingelab ----------------------------------------------------------------------------
def write_hingelab(root: Path, episodes, compression: str = "zstd", **options) -> list[Path]:
    """One EpisodeWriter per episode; ``options``: more EpisodeWriter storage options."""
    create_dataset(root, "bench", "bench", {"bench": "datasets"}, seed=0)
    paths = []
    for i, ep in enumerate(episodes):
        with EpisodeWriter(root, source="bench", seed=i, compression=compression, **options) as writer:
            for k in range(STEPS_PER_EPISODE):
                writer.write_step(k * CONTROL_DT_S, points_hand=ep["points"][k], transition={
                    "observation": ep["state"][k], "action": ep["action"][k], "reward": ep["reward"][k],
                    "terminated": False, "truncated": k == STEPS_PER_EPISODE - 1})
        paths.append(writer.path)
    return paths


def read_hingelab(paths, with_clouds: bool = True, generic: bool = False, validate: bool = True) -> list[dict]:
    topics = [S.TOPIC_STEP, S.TOPIC_POINTS] if with_clouds else [S.TOPIC_STEP]
    out = []
    for path in paths:
        ep = read_episode(path, topics=topics, generic=generic, validate=validate)
        step = ep.topics[S.TOPIC_STEP]
        arrays = {"state": step["observation"], "action": step["action"], "reward": step["reward"]}
        if with_clouds:
            arrays["points"] = ep.points
        out.append(arrays)
    return out


def read_hingelab_one_thread(paths, with_clouds: bool = True) -> list[dict]:
    """``read_hingelab`` with the parallel chunk decompression turned off."""
    threads = mcap_raw.READ_THREADS
    mcap_raw.READ_THREADS = 1
    try:
        return read_hingelab(paths, with_clouds)
    finally:
        mcap_raw.READ_THREADS = threads


def byte_breakdown(paths) -> dict[str, float]:
    """Bytes per step of hingelab files, by where they go (sums to the file size)."""
    n_steps, sizes = 0, {}

    def add(key, value):
        sizes[key] = sizes.get(key, 0) + value

    for path in paths:
        size = path.stat().st_size
        with EpisodeFile(path) as episode_file:
            cloud_id = episode_file.channels[S.TOPIC_POINTS].id
            columns_id = episode_file.channels[S.TOPIC_COLUMNS].id
            n_steps += episode_file.metadata()[S.KEY_LENGTH]
            accounted = 0
            for chunk in episode_file.summary.chunks:
                records = mcap_raw.read_chunk_records(episode_file._stream, chunk)
                kind = ("cloud" if chunk.channel_ids == {cloud_id} else
                        "columns" if chunk.channel_ids == {columns_id} else "other topics")
                add(f"{kind} chunks on disk", chunk.chunk_length)
                add(f"{kind} message indexes", chunk.message_index_length)
                accounted += chunk.chunk_length + chunk.message_index_length
                if kind == "cloud":
                    spans = mcap_raw.message_spans(records, cloud_id)
                    payload = sum(end - start for _, start, end in spans)
                    points = 12 * episode_file.channel_info(S.TOPIC_POINTS, S.CHANNEL_SHAPES_KEY)["points"][0]
                    add("cloud points (raw float32)", points * len(spans))
                    add("cloud message header (protobuf, uncompressed)", payload - points * len(spans))
                    add("cloud MCAP message record header (uncompressed)", 31 * len(spans))
                    add("cloud chunk records (uncompressed)", len(records))
            add("file header, metadata, schemas, summary, footer", size - accounted)
            add("file", size)
    return {key: value / n_steps for key, value in sizes.items()}


# --- h5py: one group per episode ------------------------------------------------------------
def write_h5py(root: Path, episodes) -> list[Path]:
    path = root / "main_data.hdf5"
    with h5py.File(path, "w") as f:
        for i, ep in enumerate(episodes):
            group = f.create_group(f"episode_{i}")
            for name, array in ep.items():
                group.create_dataset(name, data=array)
    return [path]


def read_h5py(paths, with_clouds: bool = True) -> list[dict]:
    names = ["state", "action", "reward"] + (["points"] if with_clouds else [])
    out = []
    with h5py.File(paths[0], "r") as f:
        for i in range(len(f)):  # by episode number (iterating f is alphabetical)
            group = f[f"episode_{i}"]
            out.append({n: group[n][()] for n in names})
    return out


# --- parquet: one file per episode, fixed-size lists -------------------------------------------
def write_parquet(root: Path, episodes) -> list[Path]:
    paths = []
    for i, ep in enumerate(episodes):
        table = pa.table({
            "observation.points": pa.FixedSizeListArray.from_arrays(ep["points"].reshape(-1), 256 * 3),
            "observation.state": pa.FixedSizeListArray.from_arrays(ep["state"].reshape(-1), 26),
            "action": pa.FixedSizeListArray.from_arrays(ep["action"].reshape(-1), 9),
            "next.reward": pa.array(ep["reward"]),
        })
        path = root / f"episode_{i:06d}.parquet"
        pq.write_table(table, path, use_dictionary=False)
        paths.append(path)
    return paths


def read_parquet(paths, with_clouds: bool = True) -> list[dict]:
    columns = ["observation.state", "action", "next.reward"] + (["observation.points"] if with_clouds else [])
    out = []
    for path in paths:
        table = pq.read_table(path, columns=columns)

        def flat(name, width):
            return table.column(name).combine_chunks().flatten().to_numpy().reshape(-1, width)

        arrays = {"state": flat("observation.state", 26), "action": flat("action", 9),
                  "reward": table.column("next.reward").to_numpy()}
        if with_clouds:
            arrays["points"] = flat("observation.points", 768).reshape(-1, 256, 3)
        out.append(arrays)
    return out


# --- measuring --------------------------------------------------------------------------------
def row_ratio(a: dict, b: dict, column: str) -> float:
    return a[column] / b[column]


def _best_time(fn, repeats: int) -> tuple[float, object]:
    best, result = float("inf"), None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - start)
    return best, result


def _check_equal(expected, got, name: str) -> None:
    for want, have in zip(expected, got, strict=True):
        for key, value in have.items():
            if not np.array_equal(want[key], value):
                raise AssertionError(f"{name} read back different {key} arrays")


BAG_COLUMN = "ROS 2 bag messages/s"


# A real-size camera: the Azure Kinect DK's NFOV unbinned depth mode is 640 x 576 pixels, of which
# ~100-250k give a return; the tweezer at ~0.5 m covers a few thousand of them.
REAL_SIZE_POINTS = 200_000
REAL_SIZE_TOOL_POINTS = 3_000
REAL_SIZE_CAMERA_HZ = 15.0


def ros2_import_rows(work: Path, quick: bool, repeats: int, real_size: bool = False) -> tuple[list[dict], dict]:
    """(rows, facts): the import and the bare rosbags read of one rig bag, best of ``repeats``: the
    default rig bag (1,500-point clouds at 30 Hz), or with ``real_size`` one trial of real-size clouds
    (``REAL_SIZE_POINTS`` at ``REAL_SIZE_CAMERA_HZ``). ``facts["camera_share"]``: the share of the
    import's time spent on the camera frames (decoding, TF, the cloud pipeline), from the best run."""
    if real_size:
        n_trials, label = 1, "real-size clouds"
        spec = RigBagSpec(trials=[RigTrial(duration_s=2.0 if quick else 3.0)], scene_points=REAL_SIZE_POINTS,
                          tool_points=REAL_SIZE_TOOL_POINTS, camera_hz=REAL_SIZE_CAMERA_HZ, seed=0)
    else:
        n_trials, label = (2 if quick else 6), "1,500-point clouds"
        spec = RigBagSpec(trials=[RigTrial(duration_s=3.0)] * n_trials, seed=0)
    bag = work / ("rig_bag_real_size" if real_size else "rig_bag")
    info = write_rig_bag(bag, spec)
    encoder = load_encoder()  # loaded once, as one import command loads it for all its bags

    def bare() -> int:
        count = 0
        with AnyReader([bag]) as reader:
            for connection, _, payload in reader.messages():
                reader.deserialize(payload, connection.msgtype)
                count += 1
        return count

    runs = iter(range(10 ** 6))

    def ours():
        out = work / f"imported{next(runs)}"
        return import_bags([bag], out, encoder=encoder)

    bare_s, read = _best_time(bare, repeats)
    timed = []
    for _ in range(repeats):  # the best run's own summary: its camera time is a share of its time
        start = time.perf_counter()
        (summary,) = ours()
        timed.append((time.perf_counter() - start, summary))
    ours_s, summary = min(timed, key=lambda t: t[0])
    if read != info["messages"] or summary.messages != info["messages"]:
        raise AssertionError(f"the bag has {info['messages']} messages; read {read}, imported {summary.messages}")
    rows = [{"format": f"ROS 2 bag, {label} -> episodes (hingelab datasets import-ros2)", BAG_COLUMN: read / ours_s},
            {"format": f"ROS 2 bag, {label}, bare rosbags read (AnyReader, every message deserialized)",
             BAG_COLUMN: read / bare_s}]
    facts = {"messages": read, "episodes": len(summary.episodes), "steps": summary.steps,
             "import_steps_per_s": summary.steps / ours_s, "bag_bytes": sum(p.stat().st_size for p in bag.iterdir()),
             "trials": n_trials, "import_s": ours_s, "camera_s": summary.camera_s,
             "camera_share": summary.camera_s / ours_s, "camera_frames": summary.camera_frames,
             "trial_s": spec.trials[0].duration_s,
             "scene_points": spec.scene_points, "camera_hz": spec.camera_hz}
    return rows, facts


def run(quick: bool = False) -> BenchTable:
    n_episodes = 5 if quick else 100
    repeats = 2 if quick else 3
    episodes = make_episodes(n_episodes)
    n_steps = n_episodes * STEPS_PER_EPISODE
    formats = {
        "hingelab MCAP": (write_hingelab, read_hingelab),
        "h5py, group per episode": (write_h5py, read_h5py),
        "parquet, file per episode": (write_parquet, read_parquet),
        # the storage options, same reader (not the default, not baselines)
        "(hingelab MCAP, trusted read: no CRC or digest checks)":
            (write_hingelab, lambda paths, with_clouds=True: read_hingelab(paths, with_clouds, validate=False)),
        "(hingelab MCAP, default files read with 1 thread)": (write_hingelab, read_hingelab_one_thread),
        "(hingelab MCAP, clouds uncompressed, rest zstd)":
            (lambda r, e: write_hingelab(r, e, cloud_compression="none"), read_hingelab),
        "(hingelab MCAP, clouds lz4, rest zstd)":
            (lambda r, e: write_hingelab(r, e, cloud_compression="lz4"), read_hingelab),
        "(hingelab MCAP, nothing compressed)": (lambda r, e: write_hingelab(r, e, "none"), read_hingelab),
    }
    breakdown = {}
    rows = []
    work = Path(tempfile.mkdtemp(prefix="hingelab-bench-datasets-"))
    try:
        for name, (write, read) in tqdm(formats.items(), desc="bench datasets", unit="format"):
            def fresh_write(write=write, name=name):
                folder = work / str(len(rows))
                shutil.rmtree(folder, ignore_errors=True)
                folder.mkdir(parents=True)
                return write(folder, episodes)

            write_s, paths = _best_time(fresh_write, repeats)
            read_s, arrays = _best_time(lambda: read(paths), repeats)
            _check_equal(episodes, arrays, name)
            read_tr_s, _ = _best_time(lambda: read(paths, with_clouds=False), repeats)
            size = sum(p.stat().st_size for p in paths)
            rows.append({"format": name, "write steps/s": n_steps / write_s,
                         "read steps/s (clouds + transitions)": n_steps / read_s,
                         "read steps/s (transitions)": n_steps / read_tr_s,
                         "bytes/step": size / n_steps})
            if name == "hingelab MCAP":
                breakdown = byte_breakdown(paths)
                generic_s, arrays = _best_time(lambda: read_hingelab(paths, generic=True), 1)
                _check_equal(episodes, arrays, "hingelab generic")
                hingelab_generic = {"format": "(hingelab, decoding every message)", "write steps/s": "",
                                    "read steps/s (clouds + transitions)": n_steps / generic_s,
                                    "read steps/s (transitions)": "", "bytes/step": size / n_steps}
        bag_rows, bag = ros2_import_rows(work, quick, repeats)
        big_rows, big = ros2_import_rows(work, quick, repeats, real_size=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    ours, baselines, variants = rows[0], rows[1:3], rows[3:]
    ratios = {}
    smallest = min(baselines, key=lambda r: r["bytes/step"])
    for row in (ours, *variants):
        label = "ours" if row is ours else row["format"]
        for column in ("read steps/s (clouds + transitions)", "read steps/s (transitions)", "write steps/s"):
            if row is not ours and column != "read steps/s (clouds + transitions)":
                continue
            best = max(baselines, key=lambda r: r[column])
            ratios[f"{column}: {label} / best baseline ({best['format']})"] = row[column] / best[column]
        ratios[f"bytes/step: {label} / smallest baseline ({smallest['format']})"] = (
            row["bytes/step"] / smallest["bytes/step"])
    trusted = next(r for r in variants if r["format"].startswith("(hingelab MCAP, trusted read"))
    for column in ("read steps/s (clouds + transitions)", "read steps/s (transitions)"):
        ratios[f"{column}: ours (validating) / trusted read (validate=False)"] = row_ratio(ours, trusted, column)
    ratios[f"{BAG_COLUMN}: import into episodes / bare rosbags read"] = (
        bag_rows[0][BAG_COLUMN] / bag_rows[1][BAG_COLUMN])
    ratios[f"{BAG_COLUMN}, real-size clouds: import into episodes / bare rosbags read"] = (
        big_rows[0][BAG_COLUMN] / big_rows[1][BAG_COLUMN])
    rows = [ours, *baselines, hingelab_generic, *variants, *bag_rows, *big_rows]
    return BenchTable(
        name="datasets",
        title=f"Episode datasets: {n_episodes} episodes x {STEPS_PER_EPISODE} steps "
              "(256-point cloud, 26-D state, 9-D action, reward)",
        columns=["format", "write steps/s", "read steps/s (clouds + transitions)",
                 "read steps/s (transitions)", "bytes/step", BAG_COLUMN],
        rows=rows,
        ratios=ratios,
        notes=[
            f"best of {repeats} runs per figure; every read is checked bit-exact against the written arrays",
            "hingelab writes every step as standard messages (foxglove.PointCloud on /tool/points, "
            "hingelab.Step on /step) and reads learners' arrays from the per-episode /episode/columns "
            "message plus cloud-only chunks sliced without decoding (see datasets/README.md)",
            "h5py: uncompressed contiguous datasets, one group per episode in one file; "
            "parquet: pyarrow defaults (snappy) with dictionary encoding off",
            "every hingelab read validates (the summary's and every chunk's CRC, the metadata records' "
            "digests, the clouds' positions from the chunks' own records) unless read_episode(validate=False): "
            "the trusted-read row is that opt-out on the default files",
            "the rows in parentheses are not baselines: hingelab's generic path (one protobuf decode per "
            "message), the trusted read, the default files read with one thread, and the writer's other storage "
            "options (EpisodeWriter(cloud_compression=..., compression=...), chosen per chunk); zstd on the "
            "cloud chunks is what keeps files at or under the baselines' size (noisy float32 clouds "
            "shrink ~10%, and the per-step messages plus the columns cost ~400 B/step that the "
            "baselines do not store); its decoding is most of the cloud read time, spread over the "
            "cores a reader has free (the machine's second core was shared with another job)",
            f"ROS 2 bag rows: one rig bag written with rosbags (MCAP storage, {bag['bag_bytes'] / 1e6:.1f} MB: "
            f"{bag['trials']} trials of 3 s, a 30 Hz whole-scene PointCloud2 of 1,500 points, 100 Hz JointState and "
            f"TF, 20 Hz action, 30 Hz object pose, events; {bag['messages']:,} messages) imported into "
            f"{bag['episodes']} episodes of {bag['steps']} steps in all ({bag['import_steps_per_s']:,.0f} steps/s: "
            "the alignment, the camera cloud pipeline and ToolState's registration and encoder at every 20 Hz "
            "step, the episode writer), the encoder loaded once; the baseline reads and deserializes every "
            f"message with rosbags' AnyReader and keeps nothing; the camera frames (decoding, TF, the cloud "
            f"pipeline) took {100 * bag['camera_share']:.0f}% of the import's time",
            f"ROS 2 bag rows, real-size clouds: one trial of {big['trial_s']:g} s with an "
            f"Azure Kinect-size whole-scene PointCloud2 ({big['scene_points']:,} points, {REAL_SIZE_TOOL_POINTS:,} "
            f"on the tweezer; NFOV unbinned is 640 x 576 pixels, ~100-250k with a return) at "
            f"{big['camera_hz']:g} Hz, the other topics as above ({big['bag_bytes'] / 1e6:.0f} MB, {big['messages']:,} "
            f"messages): {big['steps']} steps ({big['import_steps_per_s']:,.0f} steps/s), the camera frames "
            f"{100 * big['camera_share']:.0f}% of the import's time "
            f"({1000 * big['camera_s'] / max(1, big['camera_frames']):.0f} ms a frame over {big['camera_frames']} "
            "frames: the cloud's bytes viewed as float32, the points outside the crop box's sphere dropped in the "
            "camera frame before the transform, then the pipeline on the few thousand left)",
            "bytes per step of the default files: " + "; ".join(
                f"{key} {value:,.1f}" for key, value in breakdown.items()),
        ],
        config={"episodes": n_episodes, "steps_per_episode": STEPS_PER_EPISODE, "repeats": repeats,
                "quick": quick, "read_threads": mcap_raw.READ_THREADS, "bytes_per_step": breakdown,
                "ros2_bag": bag, "ros2_bag_real_size": big},
    )
