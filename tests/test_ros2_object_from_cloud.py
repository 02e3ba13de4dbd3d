"""``hingelab datasets import-ros2 --object-from-cloud``: a rig bag without an object pose imports with the camera's
estimate of the object. The bags are the stand-in's camera (``hingelab.ros2.sim_rig_bag``, ``camera="depth"`` or
``"points"``): heuristic trials on a 2 cm sphere, the rig camera's rendered depth with the camera path's noise, no
``/object/pose``; the writer returns the sphere's true centre and the hand's pose at every step.

The tolerance. ``ray_corrected`` on the depth bag here (measured when this test was written, these seeds): 3.5-4.9 mm
from the true centre with the rig's mask (median 4.2), 4.3-7.0 mm with the segmentation by the platform (median 4.8;
the larger errors while the tweezer's tips close in on the sphere and its cloud takes some of the sphere's points),
about 4.4 mm of it toward the camera, as analysis/objects measured ray_corrected on the stand-in (2 cm sphere:
median 3.3-5.5 mm). Asserted: the median within 6 mm and every estimate within 10 mm (the pick's success radius),
about 1 mm and 3 mm of margin. The paper's centroid, 6.9-10.0 mm off here (median 8.0, toward the camera), fails
the median: the tolerance tells the estimators apart.
"""

from __future__ import annotations

import numpy as np
import pytest

from hingelab.cli.main import main
from hingelab.episodes import read_episode
from hingelab.episodes import schemas as S
from hingelab.episodes.codec import decode_point_cloud
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.reader import EpisodeFile
from hingelab.ros2.rig_bag import RigBagSpec, RigTrial, write_rig_bag
from hingelab.ros2.sim_rig_bag import SimRigBagSpec, write_sim_rig_bag
from hingelab.sim.rig_camera import RIG_VIEW
from hingelab.training.high_level_demos import high_level_transitions

MEDIAN_MM, MAX_MM = 6.0, 10.0
HIDDEN = ((0, 3), (1, 0))  # (trial, step): the object unseen (trial 1 from its first step)


def _import(bag, out, *flags) -> int:
    return main(["datasets", "import-ros2", str(bag), "--out", str(out), "--no-progress", *flags])


def _episodes(root) -> list:
    return sorted((read_episode(p) for p in Dataset(root).paths()), key=lambda e: int(e.metadata["ros2_trial_index"]))


def _flags(episode) -> list[str]:
    """Each step's /object/estimate flag (a string: in the messages, not in the episode's columns)."""
    with EpisodeFile(episode.path) as episode_file:
        return [m.flag for _, _, m in episode_file.iter_messages([S.TOPIC_OBJECT_ESTIMATE])]


def _world(episode, trial: dict, positions_hand: np.ndarray) -> np.ndarray:
    """hand_base positions (T, 3) of the episode's steps -> the world, by the simulated hand's pose at each step."""
    states = trial["states"][:len(positions_hand)]
    rot = np.array([s["hand_rot"] for s in states])
    pos = np.array([s["hand_pos"] for s in states])
    return np.einsum("tij,tj->ti", rot, positions_hand) + pos


def _errors_mm(episode, trial: dict) -> tuple[np.ndarray, np.ndarray]:
    """(error (T,) mm of each step's /object/position from the true centre, the steps' fresh flags)."""
    estimate = episode[S.TOPIC_OBJECT_ESTIMATE]
    world = _world(episode, trial, np.asarray(episode[S.TOPIC_OBJECT]["position"], float))
    truth = np.array([s["object"] for s in trial["states"][:len(world)]])
    return 1000 * np.linalg.norm(world - truth, axis=1), estimate["fresh"].astype(bool)


@pytest.fixture(scope="module")
def depth_bag(tmp_path_factory):
    """Two heuristic trials seen by the rendered depth camera, with the simulator's mask as the rig's segmentation;
    the object unseen at trial 0's step 3 and at trial 1's first step."""
    root = tmp_path_factory.mktemp("object_from_cloud")
    info = write_sim_rig_bag(root / "bag", SimRigBagSpec(episodes=2, max_episode_steps=12, object_pose=False,
                                                         camera="depth", object_mask=True, hidden_object_steps=HIDDEN))
    return root, info


def test_a_bag_without_an_object_pose_imports_with_the_clouds_estimate(depth_bag, capsys):
    root, info = depth_bag
    # the segmentation by geometry: the mask topic named away, as on a rig that records none
    assert _import(root / "bag", root / "platform", "--object-from-cloud", "--topic", "object_mask=/none") == 0
    out = capsys.readouterr().out
    assert "object from the camera (ray_corrected, segmented by the platform)" in out
    assert "trial 1: no object estimate at the first 1 steps (first flag: no_object_points)" in out
    episodes = _episodes(root / "platform")
    assert len(episodes) == 2
    errors = []
    for episode, trial in zip(episodes, info["trials"]):
        meta = episode.metadata
        assert meta["object_perception"] == "ray_corrected" and meta["ros2_object_segmentation"] == "platform"
        assert meta["schema_version"] == S.SCHEMA_VERSION
        estimate = episode[S.TOPIC_OBJECT_ESTIMATE]
        n = meta["length"]
        assert len(estimate["position"]) == n and "true_position" not in estimate  # a rig bag: no truth
        error, fresh = _errors_mm(episode, trial)
        errors.append(error[fresh])
        assert (estimate["n_points"][fresh] >= 8).all() and (estimate["n_points"][~fresh] == 0).all()
        extent = np.asarray(estimate["extent"], float)[fresh]
        # the visible part of a 2 cm sphere (the tool's points take most of it while the tips close in)
        assert ((np.median(extent, axis=0) > 0.01) & (np.median(extent, axis=0) < 0.02)).all()
        assert extent.max() < 0.024
        # the policy's observation holds the same object position
        observed = episode[S.TOPIC_STEP]["observation"][:, 8:11]  # tool pose 6, z_bar 2, object 3, target 3
        np.testing.assert_array_equal(observed, episode[S.TOPIC_OBJECT]["position"])
        ages = episode[S.TOPIC_STEP]["info.age_object_s"]
        assert np.allclose(ages[fresh], 0.0)  # the frame is stamped at its step
    error = np.concatenate(errors)
    assert np.median(error) < MEDIAN_MM and error.max() < MAX_MM, np.round(error, 1)
    # the hidden steps: flagged, the last estimate carried (where the object was, in the world), nothing lost
    first, second = episodes
    estimate = first[S.TOPIC_OBJECT_ESTIMATE]
    assert not estimate["fresh"][3] and _flags(first)[2:5] == ["", "no_object_points", ""]
    world = _world(first, info["trials"][0], np.asarray(first[S.TOPIC_OBJECT]["position"], float))
    np.testing.assert_allclose(world[3], world[2], atol=1e-6)
    assert first[S.TOPIC_STEP]["info.age_object_s"][3] == pytest.approx(0.05)
    # a trial whose first frame does not see the object: NaN there (reported above), never a made-up position
    position = np.asarray(second[S.TOPIC_OBJECT]["position"], float)
    assert np.isnan(position[0]).all() and np.isfinite(position[1:]).all()
    assert _flags(second)[0] == "no_object_points"
    # the visible points, hand_base, read back message by message: on the sphere
    with EpisodeFile(first.path) as episode_file:
        clouds = [decode_point_cloud(m) for _, _, m in episode_file.iter_messages([S.TOPIC_OBJECT_POINTS])]
    assert len(clouds) == int(estimate["fresh"].sum())
    truth_hand = info["trials"][0]["states"][0]["hand_rot"].T @ (info["trials"][0]["states"][0]["object"]
                                                                 - info["trials"][0]["states"][0]["hand_pos"])
    assert np.linalg.norm(clouds[0] - truth_hand, axis=1).max() < 0.015


def test_the_rigs_mask_segments_the_object_and_an_empty_mask_is_flagged(depth_bag, capsys):
    root, info = depth_bag
    assert _import(root / "bag", root / "mask", "--object-from-cloud", "centroid") == 0
    assert "object from the camera (centroid, segmented by the mask)" in capsys.readouterr().out
    camera = np.array(RIG_VIEW.eye)  # the rig camera's eye, world
    toward_camera = []
    for episode, trial in zip(_episodes(root / "mask"), info["trials"]):
        assert episode.metadata["object_perception"] == "centroid"
        assert episode.metadata["ros2_object_segmentation"] == "mask"
        world = _world(episode, trial, np.asarray(episode[S.TOPIC_OBJECT]["position"], float))
        fresh = episode[S.TOPIC_OBJECT_ESTIMATE]["fresh"].astype(bool)
        truth = np.array([s["object"] for s in trial["states"][:len(world)]])
        ray = (camera - truth) / np.linalg.norm(camera - truth, axis=1, keepdims=True)
        toward_camera.append(np.einsum("ti,ti->t", world - truth, ray)[fresh])
    first = _episodes(root / "mask")[0]
    assert not first[S.TOPIC_OBJECT_ESTIMATE]["fresh"][3] and _flags(first)[3] == "no_object_pixels"  # empty mask
    # the paper's centroid of the masked points lies toward the camera by a few mm, at most half the sphere
    assert 0.004 < np.median(np.concatenate(toward_camera)) < 0.010


def test_a_scene_cloud_imports_the_same_way_and_without_the_flag_the_object_is_left_out(tmp_path, capsys):
    info = write_sim_rig_bag(tmp_path / "bag", SimRigBagSpec(episodes=1, max_episode_steps=5, object_pose=False,
                                                             camera="points", hidden_object_steps=((0, 3),)))
    assert _import(tmp_path / "bag", tmp_path / "estimated", "--object-from-cloud") == 0
    (episode,) = _episodes(tmp_path / "estimated")
    error, fresh = _errors_mm(episode, info["trials"][0])
    assert list(fresh) == [True, True, True, False, True, True]
    assert np.median(error) < MEDIAN_MM and error.max() < MAX_MM, np.round(error, 1)
    # without the flag: imported without an object (as before), the summary names the flag, train high refuses
    capsys.readouterr()
    assert _import(tmp_path / "bag", tmp_path / "no_object") == 0
    out = capsys.readouterr().out
    assert "no object pose (/object/pose)" in out and "--object-from-cloud estimates it" in out
    (episode,) = _episodes(tmp_path / "no_object")
    assert S.TOPIC_OBJECT not in episode.topics and "object_perception" not in episode.metadata
    with pytest.raises(DatasetError) as err:
        high_level_transitions([tmp_path / "no_object"])
    line = str(err.value)
    assert "\n" not in line and "--object-from-cloud" in line and "(from bag bag)" in line


def test_the_flag_forces_the_estimate_and_a_bag_that_never_sees_one_is_reported(tmp_path, capsys):
    """A bag with an object pose: the flag still estimates from the camera, the pose beside it as its reference;
    the synthetic rig bag's camera sees no object on the platform, so every step is flagged and NaN."""
    write_rig_bag(tmp_path / "bag", RigBagSpec(trials=[RigTrial(duration_s=0.3)], gap_s=0.2))
    assert _import(tmp_path / "bag", tmp_path / "out", "--object-from-cloud", "primitive_fit") == 0
    out = capsys.readouterr().out
    assert "trial 0: no object estimate at any of its 7 steps (first flag: no_object_points)" in out
    (episode,) = _episodes(tmp_path / "out")
    estimate = episode[S.TOPIC_OBJECT_ESTIMATE]
    assert episode.metadata["object_perception"] == "primitive_fit"
    assert np.isnan(episode[S.TOPIC_OBJECT]["position"]).all() and not estimate["fresh"].any()
    assert np.isfinite(estimate["true_position"]).all()  # the bag's /object/pose, in hand_base


def test_bad_uses_of_the_flag_are_one_line(tmp_path, capsys):
    write_rig_bag(tmp_path / "bag", RigBagSpec(trials=[RigTrial(duration_s=0.3)], gap_s=0.2,
                                               topics={"points": "/tool/points"}))  # a tool cloud, no scene
    assert _import(tmp_path / "bag", tmp_path / "a", "--object-from-cloud") == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--object-from-cloud estimates the object from the scene's camera" in err[0]
    assert str(tmp_path / "bag") in err[0] and not (tmp_path / "a").exists()
    assert _import(tmp_path / "bag", tmp_path / "b", "--object-from-cloud", "median") == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "ray_corrected" in err[0] and "'median'" in err[0]
