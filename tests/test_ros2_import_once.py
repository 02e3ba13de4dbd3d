"""``datasets import-ros2`` is idempotent: a bag's trial already in the dataset ``--out`` (the same topics
and time range, whatever the bag's file is called now) is skipped with a line saying so, not imported twice."""

from __future__ import annotations

import shutil

import pytest

from hingelab.cli.main import main
from hingelab.episodes.dataset import Dataset
from hingelab.ros2.rig_bag import RigBagSpec, RigTrial, write_rig_bag


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    root = tmp_path_factory.mktemp("bags")
    write_rig_bag(root / "two", RigBagSpec(trials=[RigTrial(duration_s=0.3), RigTrial(duration_s=0.3)], gap_s=0.2))
    write_rig_bag(root / "other", RigBagSpec(trials=[RigTrial(duration_s=0.4)], gap_s=0.3))
    return root


def _import(*args) -> int:
    return main(["datasets", "import-ros2", *map(str, args), "--no-progress"])


def test_the_same_bag_imported_twice_into_one_out_is_skipped_the_second_time(bags, tmp_path, capsys):
    out = tmp_path / "real"
    assert _import(bags / "two", "--out", out) == 0
    first = Dataset(out).index
    assert len(first) == 2
    capsys.readouterr()

    assert _import(bags / "two", "--out", out) == 0
    text = capsys.readouterr().out
    assert "two: 0 episodes" in text and "2 trials already in" in text and "skipped" in text
    pd_files = list(Dataset(out).index["file"])
    assert pd_files == list(first["file"])  # the same two episodes, none added

    # a copy of the bag under another name is the same recording: skipped too; another bag is imported
    shutil.copytree(bags / "two", tmp_path / "renamed")
    assert _import(tmp_path / "renamed", bags / "other", "--out", out) == 0
    text = capsys.readouterr().out
    assert "renamed: 0 episodes" in text and "other: 1 episodes" in text
    assert len(Dataset(out).index) == 3


def test_a_bag_given_twice_on_one_command_line_is_imported_once(bags, tmp_path, capsys):
    out = tmp_path / "real"
    assert _import(bags / "two", bags / "two", "--out", out) == 0
    assert len(Dataset(out).index) == 2
    assert "2 trials already in" in capsys.readouterr().out
