"""The depth camera and the camera cloud pipeline: hand-made frames, rendered frames, noise, bad frames."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from hingelab.camera import AZURE_KINECT_NFOV_UNBINNED, CameraFrame, DepthIntrinsics
from hingelab.errors import ConfigError
from hingelab.perception import camera_cloud as cc

SMALL = DepthIntrinsics("test", 80, 60, 100.0, 100.0, 40.0, 30.0, 0.2, 3.0)


def box_frame(tool_depth=0.55, wall_depth=0.8):
    """A wall with a 20 x 16 pixel block nearer the camera; the block is the 'tool'."""
    depth = np.full((SMALL.height, SMALL.width), wall_depth, np.float32)
    mask = np.zeros(depth.shape, bool)
    mask[20:36, 30:50] = True
    depth[mask] = tool_depth
    return CameraFrame(depth=depth, intrinsics=SMALL, camera_rotation=np.eye(3), camera_position=np.zeros(3),
                       tool_mask=mask)


def test_depth_to_points_follows_the_pinhole_model():
    frame = box_frame()
    points = cc.depth_to_points(frame.depth, SMALL, frame.tool_mask)
    assert len(points) == 20 * 16
    # pixel (u=30, v=20) at 0.55 m: x = (30 - 40) * 0.55 / 100, y = (20 - 30) * 0.55 / 100
    np.testing.assert_allclose(points[0], [-0.055, -0.055, 0.55], atol=1e-7)
    assert len(cc.depth_to_points(frame.depth, SMALL)) == SMALL.width * SMALL.height


def test_outliers_voxels_and_exact_sampling():
    rng = np.random.default_rng(0)
    cluster = rng.normal(0, 0.003, (500, 3))
    stray = np.array([[0.2, 0.2, 0.2]])
    kept = cc.remove_statistical_outliers(np.concatenate([cluster, stray]), 16, 2.0)
    assert not np.any(np.all(kept == stray, axis=1)) and len(kept) >= 450
    # two points in one 2 mm voxel become their mean; a third far away stays itself
    pts = np.array([[0.0, 0.0, 0.0], [0.001, 0.001, 0.001], [0.01, 0.0, 0.0]])
    vox = cc.voxel_downsample(pts, 0.002)
    assert len(vox) == 2
    assert any(np.allclose(v, [0.0005, 0.0005, 0.0005]) for v in vox)
    few = cc.sample_exactly(vox, 256, rng)
    assert few.shape == (256, 3) and len(np.unique(few, axis=0)) == 2
    many = cc.sample_exactly(cluster, 256, rng)
    assert len(np.unique(many, axis=0)) == 256


def test_the_chain_on_a_hand_made_frame_gives_256_points_in_the_hand_frame():
    frame = box_frame()
    # the camera 1 m along hand_base x, looking back along -x: optical z -> hand -x
    frame.camera_rotation = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    frame.camera_position = np.array([1.0, 0.0, 0.0])
    config = cc.ToolCloudConfig(crop_low=(0.3, -0.2, -0.2), crop_high=(0.6, 0.2, 0.2))
    cloud = cc.tool_cloud_from_frame(frame, config, np.random.default_rng(0))
    assert cloud.flag is None and cloud.points.shape == (256, 3)
    np.testing.assert_allclose(cloud.points[:, 0], 0.45, atol=1e-6)  # 1 m - 0.55 m
    assert cloud.counts["tool_pixels"] == 320 and cloud.counts["cropped"] == 320
    assert 0 < cloud.n_distinct <= 256
    # without the mask the crop alone keeps the block (the wall at 0.8 m is 0.2 m from the hand: cropped away)
    bare = cc.tool_cloud_from_frame(frame, config, np.random.default_rng(0), mask=np.ones_like(frame.tool_mask))
    assert bare.counts["cropped"] == 320


def test_empty_and_toolless_frames_are_flagged_not_raised():
    frame = box_frame()
    frame.depth[:] = 0
    assert cc.tool_cloud_from_frame(frame, cc.ToolCloudConfig(), np.random.default_rng(0)).flag == "no_depth"
    frame = box_frame()
    frame.tool_mask[:] = False
    result = cc.tool_cloud_from_frame(frame, cc.ToolCloudConfig(), np.random.default_rng(0))
    assert result.flag == "no_tool_pixels" and result.points is None


def test_colour_and_depth_threshold_mask_for_real_rgbd_frames():
    frame = box_frame()
    rgb = np.zeros((SMALL.height, SMALL.width, 3), np.uint8)
    rgb[frame.tool_mask] = (30, 200, 40)  # the printed tweezer's green
    rgb[0:5, 0:5] = (30, 200, 40)  # the same colour on the far wall: cut by the depth window
    frame.depth[0:5, 0:5] = 1.5
    mask = cc.colour_depth_mask(rgb, frame.depth, (35, 190, 50), tolerance=30, depth_range=(0.3, 1.2))
    assert np.array_equal(mask, frame.tool_mask)


def test_frame_shapes_are_checked():
    with pytest.raises(ConfigError, match="does not match"):
        CameraFrame(np.zeros((10, 10), np.float32), SMALL, np.eye(3), np.zeros(3))


def test_depth_noise_grows_with_range_and_drops_edges():
    from hingelab.sim.depth_noise import NO_NOISE, DepthNoise, silhouette

    rng = np.random.default_rng(0)
    flat = DepthNoise(edge_drop=0.0, dropout=0.0)
    near = flat.apply(np.full((60, 80), 0.6, np.float32), SMALL, rng)
    far = flat.apply(np.full((60, 80), 2.5, np.float32), SMALL, rng)
    expected = [flat.base_m + flat.quadratic_m_per_m2 * d * d for d in (0.6, 2.5)]
    assert np.std(near) == pytest.approx(expected[0], rel=0.1)
    assert np.std(far) == pytest.approx(expected[1], rel=0.1)
    frame = box_frame()
    edges = silhouette(frame.depth, 0.01)
    # both sides of the block's outline: its border pixels (68) and the wall pixels 4-adjacent to it (72)
    assert edges.sum() == (2 * 20 + 2 * 16 - 4) + (2 * 20 + 2 * 16)
    dropped = DepthNoise(edge_drop=1.0, dropout=0.0).apply(frame.depth, SMALL, rng)
    assert np.all(dropped[edges] == 0) and np.all(dropped[~edges] > 0)
    assert np.array_equal(NO_NOISE.apply(frame.depth, SMALL, rng), frame.depth)


def test_grazing_surfaces_lose_their_returns():
    from hingelab.sim.depth_noise import DepthNoise, incidence_angle_deg

    v = np.arange(SMALL.height, dtype=np.float32)[:, None]
    # a floor seen nearly edge-on: depth grows fast down the image
    steep = np.broadcast_to(0.5 * np.exp(v / 6.0), (SMALL.height, SMALL.width)).astype(np.float32)
    angle = incidence_angle_deg(steep, SMALL)
    assert np.median(angle[5:-5, 5:-5]) > 80
    facing = incidence_angle_deg(np.full((SMALL.height, SMALL.width), 0.6, np.float32), SMALL)
    assert facing[30, 40] < 1
    noisy = DepthNoise(edge_drop=0.0, dropout=0.0).apply(np.where(steep < 3, steep, 0), SMALL,
                                                         np.random.default_rng(0))
    assert (noisy[5:-5, 5:-5] == 0).mean() > 0.5


@pytest.fixture(scope="module")
def pick_sim():
    from hingelab.sim.core import SimCore

    sim = SimCore("tool_pick", camera=AZURE_KINECT_NFOV_UNBINNED)
    sim.reset(seed=0)
    return sim


def test_rendered_frame_matches_the_scene(pick_sim):
    from hingelab.perception.clouds import IDEAL, CloudSynthesizer
    from hingelab.sim import names
    from hingelab.sim.depth_render import DepthRenderer
    from hingelab.sim.rig_camera import camera_pose_world

    renderer = DepthRenderer(pick_sim.model, AZURE_KINECT_NFOV_UNBINNED)
    try:
        frame = renderer.render(pick_sim.data)
    finally:
        renderer.close()
    k = frame.intrinsics
    # the object's centre projects onto a pixel whose depth is its front surface (1 cm radius nearer)
    rot, pos = camera_pose_world(pick_sim.model, pick_sim.data)
    centre = rot.T @ (pick_sim.data.body(names.OBJECT_BODY).xpos - pos)
    u, v = k.fx * centre[0] / centre[2] + k.cx, k.fy * centre[1] / centre[2] + k.cy
    assert frame.depth[int(v), int(u)] == pytest.approx(centre[2] - 0.01, abs=0.003)
    assert frame.tool_mask.sum() > 300
    cloud = cc.tool_cloud_from_frame(frame, cc.ToolCloudConfig(), np.random.default_rng(0))
    assert cloud.flag is None and cloud.points.shape == (256, 3)
    # every camera point lies on the tool's surface: near the ideal synthesized cloud (~5 mm spacing)
    from scipy.spatial import cKDTree

    ideal = CloudSynthesizer(realism=IDEAL).from_sim(pick_sim.model, pick_sim.data)
    distance, _ = cKDTree(ideal).query(cloud.points)
    assert np.median(distance) < 0.004 and np.percentile(distance, 95) < 0.008


def test_no_gl_backend_is_one_line_naming_mujoco_gl():
    import os

    code = ("from hingelab.sim.core import SimCore\n"
            "from hingelab.camera import AZURE_KINECT_NFOV_UNBINNED as K\n"
            "from hingelab.sim.depth_render import DepthRenderer\n"
            "from hingelab.errors import ConfigError\n"
            "try:\n"
            "    DepthRenderer(SimCore('tool_pick', camera=K).model, K)\n"
            "except ConfigError as exc:\n"
            "    print('ERR', exc)\n")
    # glfw without a display: MuJoCo imports, but no GL context can be made
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**env, "MUJOCO_GL": "glfw"}, timeout=120)
    line = [x for x in out.stdout.splitlines() if x.startswith("ERR")]
    assert line and "MUJOCO_GL=glfw" in line[0] and "egl" in line[0]
    # a value MuJoCo rejects at import: the command says so in one line instead of a traceback
    out = subprocess.run([sys.executable, "-m", "hingelab.cli.main", "eval", "perception", "--out", "x"],
                         capture_output=True, text=True, env={**env, "MUJOCO_GL": "no-such-backend"}, timeout=120)
    assert out.returncode == 1 and "Traceback" not in out.stderr
    assert out.stderr.strip().count("\n") == 0 and "MUJOCO_GL=no-such-backend" in out.stderr


def test_a_headless_shell_renders_without_setting_mujoco_gl():
    """A fresh shell has no MUJOCO_GL: hingelab picks EGL before mujoco is imported (the demo's trial step)."""
    import os

    code = ("import hingelab.cli.main, os\n"  # the CLI's imports first, as `hingelab demo` runs them
            "from hingelab.sim.core import SimCore\n"
            "from hingelab.camera import AZURE_KINECT_NFOV_UNBINNED as K\n"
            "from hingelab.sim.depth_render import DepthRenderer\n"
            "sim = SimCore('tool_pick', camera=K)\nsim.reset(seed=0)\n"
            "frame = DepthRenderer(sim.model, K).render(sim.data)\n"
            "print('GL', os.environ['MUJOCO_GL'], int((frame.depth > 0).sum()))\n")
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "MUJOCO_GL")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    line = [x for x in out.stdout.splitlines() if x.startswith("GL")]
    assert line, out.stderr[-2000:]
    _, backend, valid = line[0].split()
    assert backend == "egl" and int(valid) > 1000


def test_the_egl_default_is_linux_only(monkeypatch):
    """macOS and Windows have no DISPLAY either, and there mujoco's import refuses MUJOCO_GL=egl."""
    import hingelab

    for platform, expected in (("darwin", None), ("win32", None), ("linux", "egl")):
        monkeypatch.delenv("MUJOCO_GL", raising=False)
        monkeypatch.delenv("DISPLAY", raising=False)
        monkeypatch.setattr(sys, "platform", platform)
        hingelab._default_gl_backend()
        assert os.environ.get("MUJOCO_GL") == expected, platform
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.delenv("MUJOCO_GL")
    hingelab._default_gl_backend()
    assert "MUJOCO_GL" not in os.environ  # a display: mujoco's own default (glfw)
