"""Bounded reads: a mesh file far too large is refused from its size before it is read; a PointCloud2
whose header does not describe its data is one line naming the bag and topic; a dangling symlink or a
symlink loop is reported as an unreadable file (never a traceback); a cut-off bag's drop counts are what
was read, not what its metadata.yaml says."""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from hingelab.bounded_reads import resolved_input, unreadable_reason
from hingelab.cli.main import main
from hingelab.episodes import create_dataset
from hingelab.episodes.dataset import Dataset, corrupt_policy
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.synthetic import write_synthetic_episode
from hingelab.errors import ConfigError
from hingelab.ros2 import rig_bag
from hingelab.ros2.ros_messages import cloud_xyz, depth_image_m
from hingelab.sim.mesh_objects import MAX_MESH_MB_ENV, load_unit_hull


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("hingelab: error: ") and "Traceback" not in "\n".join(err)
    return err[-1]


# ------------------------------------------------------------------------------------------- meshes
@pytest.fixture
def huge_mesh(tmp_path) -> Path:
    """A 1 GB sparse STL: no disk used, but reading it whole would take seconds and gigabytes."""
    path = tmp_path / "huge.stl"
    with open(path, "wb") as f:
        f.truncate(1 << 30)
    return path


def test_a_huge_mesh_is_refused_before_it_is_read(huge_mesh, monkeypatch):
    monkeypatch.delenv(MAX_MESH_MB_ENV, raising=False)
    started = time.perf_counter()
    with pytest.raises(ConfigError) as caught:
        load_unit_hull(f"mesh:{huge_mesh}")
    assert time.perf_counter() - started < 0.5
    message = str(caught.value)
    assert "\n" not in message and str(huge_mesh) in message and "1.1 GB" in message and "200.0 MB" in message
    assert "--max-mesh-mb" in message


def test_generate_refuses_a_huge_mesh_in_one_line(huge_mesh, tmp_path, monkeypatch, capsys):
    monkeypatch.delenv(MAX_MESH_MB_ENV, raising=False)
    assert main(["generate", "heuristic", "--object", f"mesh:{huge_mesh}", "--episodes", "1",
                 "--out", str(tmp_path / "demos")]) == 1
    assert "above the 200.0 MB limit" in _one_line_error(capsys)


def test_the_limit_is_raised_by_the_flag_and_the_environment(tmp_path, monkeypatch):
    import trimesh

    box = tmp_path / "box.stl"
    trimesh.creation.box(extents=[1.0, 1.0, 1.0]).export(box)  # 684 bytes
    monkeypatch.setenv(MAX_MESH_MB_ENV, "0.0001")  # 100 bytes
    with pytest.raises(ConfigError, match="above the 100 bytes limit"):
        load_unit_hull(f"mesh:{box}")
    monkeypatch.setenv(MAX_MESH_MB_ENV, "0.01")
    assert len(load_unit_hull(f"mesh:{box}").vertices) == 8
    monkeypatch.setenv(MAX_MESH_MB_ENV, "lots")
    with pytest.raises(ConfigError, match="not a size in MB"):
        load_unit_hull(f"mesh:{box}")
    from hingelab.cli.main import build_parser

    monkeypatch.delenv(MAX_MESH_MB_ENV)
    for argv in (["generate", "heuristic", "--out", "x"], ["trial", "--out", "x"], ["eval", "high", "--out", "x"],
                 ["train", "high"]):
        args = build_parser(argv + ["--max-mesh-mb", "500"]).parse_args(argv + ["--max-mesh-mb", "500"])
        assert args.max_mesh_mb == 500 and os.environ[MAX_MESH_MB_ENV] == "500.0"  # workers inherit it
        monkeypatch.delenv(MAX_MESH_MB_ENV)


def test_a_mesh_path_that_is_a_symlink_loop_is_one_line(tmp_path):
    loop = tmp_path / "loop.stl"
    loop.symlink_to(loop)
    with pytest.raises(ConfigError, match="symlink loop"):
        load_unit_hull(f"mesh:{loop}")


# ------------------------------------------------------------------------------------------- PointCloud2
def _cloud(n: int = 50, **change):
    ts = get_typestore(Stores.ROS2_HUMBLE)
    msg = rig_bag.point_cloud2(ts, 10**9, "camera", np.random.default_rng(0).normal(size=(n, 3)))
    for name, value in change.items():
        setattr(msg, name, value)
    return msg


def _fields(**datatype_offset):
    ts = get_typestore(Stores.ROS2_HUMBLE)
    return [ts.types["sensor_msgs/msg/PointField"](name=n, offset=o, datatype=d, count=1)
            for n, (d, o) in datatype_offset.items()]


WHERE = "rig.mcap: /camera/depth/points at 1.000 s"
BAD_CLOUDS = {
    "point_step 0": dict(point_step=0),
    "field beyond point_step": dict(fields=_fields(x=(7, 0), y=(7, 4), z=(7, 12))),
    "unknown datatype": dict(fields=_fields(x=(7, 0), y=(7, 4), z=(99, 8))),
    "row_step short": dict(height=2, width=25, row_step=25 * 12 - 4),
    "row_step long": dict(row_step=50 * 12 + 400),
    "data short": dict(width=10**9, row_step=12 * 10**9),
}


@pytest.mark.parametrize("case", sorted(BAD_CLOUDS))
def test_a_point_cloud2_header_that_lies_is_one_line_naming_the_topic(case):
    with pytest.raises(DatasetError) as caught:
        cloud_xyz(_cloud(**BAD_CLOUDS[case]), WHERE)
    message = str(caught.value)
    assert message.startswith(WHERE + ": PointCloud2") and "\n" not in message


def test_sound_point_clouds_still_read_padded_rows_too():
    points = np.random.default_rng(1).normal(size=(6, 3)).astype("<f4")
    assert np.allclose(cloud_xyz(_cloud(6, data=points.view(np.uint8).ravel()), WHERE), points)
    padded = np.zeros((2, 3 * 12 + 4), np.uint8)  # two rows of three points, four bytes of padding each
    padded[:, :36] = points.view(np.uint8).reshape(2, 36)
    msg = _cloud(6, height=2, width=3, row_step=40, data=padded.ravel())
    assert np.allclose(cloud_xyz(msg, WHERE), points)


def test_a_depth_image_shorter_than_its_header_is_one_line():
    ts = get_typestore(Stores.ROS2_HUMBLE)
    msg = ts.types["sensor_msgs/msg/Image"](header=rig_bag._header(ts, 0), height=4, width=4, encoding="32FC1",
                                            is_bigendian=0, step=16, data=np.zeros(60, np.uint8))
    with pytest.raises(DatasetError, match="depth image of 4 x 4 32FC1 with step 16 holds 60 bytes"):
        depth_image_m(msg, WHERE)


def test_import_of_a_bag_with_a_bad_point_cloud2_is_one_line_and_leaves_no_dataset(tmp_path, monkeypatch, capsys):
    original = rig_bag.point_cloud2

    def zero_step(ts, stamp_ns, frame_id, points):
        msg = original(ts, stamp_ns, frame_id, points)
        msg.point_step = 0
        return msg

    monkeypatch.setattr(rig_bag, "point_cloud2", zero_step)
    rig_bag.write_rig_bag(tmp_path / "bag", rig_bag.RigBagSpec(trials=[rig_bag.RigTrial(duration_s=0.3)], gap_s=0.2))
    out = tmp_path / "real"
    assert main(["datasets", "import-ros2", str(tmp_path / "bag"), "--out", str(out), "--no-progress"]) == 1
    line = _one_line_error(capsys)
    assert "/camera/depth/points at" in line and "point_step 0" in line
    assert not out.exists()


# ------------------------------------------------------------------------------------------- symlinks
@pytest.fixture
def linked(tmp_path) -> Path:
    """A dataset of two sound episodes, a dangling .mcap symlink and a .mcap symlink loop."""
    root = tmp_path / "linked"
    create_dataset(root, name="linked", source="synthetic", seed=0, config={})
    for seed in range(2):
        write_synthetic_episode(root, seed, n_steps=4)
    (root / "episodes" / "gone.mcap").symlink_to(tmp_path / "moved_away.mcap")
    (root / "episodes" / "loop.mcap").symlink_to(root / "episodes" / "loop.mcap")
    return root


def test_unreadable_reason_names_dangling_links_and_loops(linked):
    assert "dangling symlink" in unreadable_reason(linked / "episodes" / "gone.mcap")
    assert "symlink loop" in unreadable_reason(linked / "episodes" / "loop.mcap")
    assert unreadable_reason(linked / "dataset.json") is None
    assert unreadable_reason(linked, "folder") is None and "folder" in unreadable_reason(linked)


@pytest.mark.parametrize("verb", ["info", "index"])
def test_datasets_info_and_index_report_dangling_links_and_loops(linked, verb, capsys):
    assert main(["datasets", verb, str(linked)]) == 1
    line = _one_line_error(capsys)
    assert "2 of 4 episode files cannot be read (gone.mcap, loop.mcap)" in line and "dangling symlink" in line
    assert main(["datasets", verb, str(linked), "--on-corrupt", "skip"]) == 0
    assert "left out 2 of 4" in capsys.readouterr().err


def test_report_reports_dangling_links_and_loops(linked, tmp_path, capsys):
    assert main(["report", str(linked), "--out", str(tmp_path / "report")]) == 1
    assert "gone.mcap" in _one_line_error(capsys)


def test_verify_reports_them_as_unreadable(linked, capsys):
    assert main(["datasets", "verify", str(linked)]) == 1
    err = capsys.readouterr().err
    assert "gone.mcap: unreadable: is a dangling symlink" in err and "loop.mcap: unreadable: is a symlink loop" in err
    assert "2 bad file(s) of 4" in err


def test_iteration_under_skip_leaves_them_out(linked):
    with corrupt_policy("skip"):
        dataset = Dataset(linked)
        assert len(list(dataset.iter_episodes())) == 2


def test_train_high_from_a_symlink_loop_is_one_line(tmp_path, capsys):
    loop = tmp_path / "demos"
    loop.symlink_to(loop)
    out = tmp_path / "run"
    assert main(["train", "high", "--from", str(loop), "--steps", "60", "--out", str(out), "--no-progress"]) == 1
    line = _one_line_error(capsys)
    assert "--from" in line and "symlink loop" in line and not out.exists()
    with pytest.raises(ConfigError, match="--init-from .* symlink loop"):
        resolved_input(loop, "--init-from")


# ------------------------------------------------------------------------------------------- cut-off bags
def test_a_cut_off_bag_counts_what_was_read_not_what_metadata_yaml_says(tmp_path, capsys):
    from mcap.reader import make_reader

    from hingelab.ros2.bag_source import open_bag

    rig_bag.write_rig_bag(tmp_path / "bag", rig_bag.RigBagSpec(trials=[rig_bag.RigTrial(duration_s=0.6)] * 4,
                                                               gap_s=0.3))
    cut = tmp_path / "cut"
    shutil.copytree(tmp_path / "bag", cut)
    (mcap_file,) = cut.glob("*.mcap")
    with open(mcap_file, "rb") as f:
        chunks = sorted(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    with open(mcap_file, "r+b") as f:
        f.truncate(chunks[1].chunk_start_offset + chunks[1].chunk_length // 2)
    meta = cut / "metadata.yaml"
    meta.write_text(meta.read_text().replace("message_count: ", "message_count: 999999999"))  # a lie
    bag = open_bag(cut)
    read = sum(bag.counts.values())
    assert f"{read} messages read" in bag.cut_off
    assert main(["datasets", "import-ros2", str(cut), "--out", str(tmp_path / "a"), "--no-progress"]) == 0
    out = capsys.readouterr().out
    dropped = out.split("dropped:")[1].split(" Note:")[0]
    assert "99999999" not in dropped and "cut-off" not in dropped  # no drop count from the lying file
    assert f"{read} messages read" in out and "metadata.yaml lists" in out
