"""The object's position from rendered depth frames: the centroid's bias toward the camera, the ray-corrected
estimate, flagged frames (empty mask, hidden by the tool, off the platform), seeded mask errors, the filter and
``hingelab diagnose object-estimate``'s files."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from hingelab.camera import AZURE_KINECT_NFOV_UNBINNED as RIG
from hingelab.errors import ConfigError
from hingelab.perception import object_estimate as oe
from hingelab.perception.camera_cloud import depth_to_points, transform
from hingelab.perception.object_model_fit import ObjectModel
from hingelab.rollouts import object_estimate_errors
from hingelab.sim import names, scripted
from hingelab.sim.core import SimCore
from hingelab.sim.depth_noise import DepthNoise
from hingelab.sim.object_render import ObjectDepthRenderer, platform_crop, true_object_centre
from hingelab.sim.objects import ObjectSpec


class Scene:
    """The stand-in's scene with one object, the rig's camera and the platform's crop."""

    def __init__(self, obj: ObjectSpec):
        self.obj = obj
        self.sim = SimCore("tool_pick", obj=obj, camera=RIG)
        self.sim.reset(seed=0, object_xy=scripted.platform_center(self.sim.model))
        self.renderer = ObjectDepthRenderer(self.sim.model, RIG)
        self.config = oe.ObjectCloudConfig(*platform_crop(self.sim.model))

    def move_object(self, position) -> None:
        m, d = self.sim.model, self.sim.data
        adr = m.jnt_qposadr[m.joint(names.OBJECT_FREE_JOINT).id]
        d.qpos[adr:adr + 3] = position
        mujoco.mj_forward(m, d)

    def render(self):
        return self.renderer.render(self.sim.data), true_object_centre(self.sim.model, self.sim.data, self.obj)


@pytest.fixture(scope="module")
def sphere():
    scene = Scene(ObjectSpec("sphere", 0.02))
    yield scene
    scene.renderer.close()


def ray_bias(estimate, truth, camera):
    """The error's component along the ray camera -> truth, positive toward the camera (m), and across it."""
    ray = (truth - camera) / np.linalg.norm(truth - camera)
    error = estimate - truth
    return -float(error @ ray), float(np.linalg.norm(error - (error @ ray) * ray))


def test_the_camera_sees_the_object_on_the_platform(sphere):
    rendered, _ = sphere.render()
    assert rendered.object_mask.sum() > 80  # a 2 cm sphere at ~0.65 m: ~150 pixels
    assert not (rendered.object_mask & rendered.frame.tool_mask).any()


def test_centroid_lies_toward_the_camera_by_at_most_half_the_depth(sphere):
    rendered, truth = sphere.render()
    result = oe.estimate_object(rendered.frame, rendered.object_mask, "centroid", sphere.config)
    assert result.flag is None and result.n_points > 50
    along, across = ray_bias(result.estimate, truth, rendered.frame.camera_position)
    radius = sphere.obj.size / 2  # half the sphere's depth along any ray
    assert 0.3 * radius < along <= radius  # a visible cap's mean: 2/3 r toward the camera for a whole hemisphere
    assert across < 0.002
    np.testing.assert_array_less(result.extent, sphere.obj.size + 0.002)  # the visible box is within the object's


def test_ray_corrected_and_the_sphere_fit_are_closer_than_the_centroid_on_a_sphere(sphere):
    rendered, truth = sphere.render()
    rng = np.random.default_rng(3)
    frame = rendered.frame
    frame.depth = DepthNoise().apply(frame.depth, RIG, rng)
    mask = oe.MaskErrors(wrong_blob=0.0).apply(rendered.object_mask, rng)
    cloud = oe.object_cloud(frame, mask, sphere.config)
    model = ObjectModel.from_mujoco(sphere.sim.model)
    error = {name: np.linalg.norm(oe.estimate_object(frame, mask, name, sphere.config, cloud=cloud,
                                                     object_model=model).estimate - truth)
             for name in oe.ESTIMATORS}
    assert error["ray_corrected"] < error["centroid"]
    assert error["primitive_fit"] < error["centroid"]
    centre, radius = oe.fit_sphere(cloud.points, frame.camera_position)
    assert abs(radius - sphere.obj.size / 2) < 0.003


def test_an_empty_mask_is_flagged(sphere):
    rendered, truth = sphere.render()
    result = oe.estimate_object(rendered.frame, np.zeros_like(rendered.object_mask), "ray_corrected", sphere.config)
    assert result.estimate is None and result.extent is None and result.flag == "no_object_pixels"
    blank = rendered.frame
    blank.depth = np.zeros_like(blank.depth)
    assert oe.estimate_object(blank, rendered.object_mask, config=sphere.config).flag == "no_depth"


def test_an_object_hidden_by_the_tool_is_flagged():
    scene = Scene(ObjectSpec("sphere", 0.01))
    try:
        rendered, _ = scene.render()
        frame = rendered.frame
        tool = transform(depth_to_points(frame.depth, RIG, frame.tool_mask), frame.camera_rotation,
                         frame.camera_position)
        point = tool[np.argmin(np.linalg.norm(tool - np.median(tool, axis=0), axis=1))]  # on the tweezer
        ray = (point - frame.camera_position) / np.linalg.norm(point - frame.camera_position)
        scene.move_object(point + 0.03 * ray)  # 3 cm behind the tweezer, on the camera's line of sight
        rendered, truth = scene.render()
        assert rendered.object_mask.sum() == 0
        hidden = oe.estimate_object(rendered.frame, rendered.object_mask, config=scene.config, prior=truth)
        assert hidden.estimate is None and hidden.flag == "hidden_by_tool"
        # without knowing where it was, an empty mask is all the frame says
        assert oe.estimate_object(rendered.frame, rendered.object_mask, config=scene.config).flag == "no_object_pixels"
    finally:
        scene.renderer.close()


def test_an_object_off_the_platform_is_flagged(sphere):
    sphere.move_object((0.62, 0.0, sphere.obj.size / 2))  # on the table in front of the platform
    try:
        rendered, _ = sphere.render()
        assert rendered.object_mask.sum() > 20  # seen, but outside the platform's box
        result = oe.estimate_object(rendered.frame, rendered.object_mask, "primitive_fit", sphere.config)
        assert result.estimate is None and result.flag == "off_platform"
    finally:
        sphere.sim.reset(seed=0, object_xy=scripted.platform_center(sphere.sim.model))


def test_without_a_mask_the_object_is_the_cluster_resting_on_the_platform():
    """``object_cloud_from_scene`` on a made-up scene: a noisy platform top, a 2 cm sphere's upper half on it, a
    blob floating 4 cm over it (a finger); the tool's points over the sphere hide it."""
    rng = np.random.default_rng(0)
    config = oe.ObjectCloudConfig(crop_low=(0.4, -0.1, 0.202), crop_high=(0.6, 0.1, 0.26))  # the platform's top at 0.2
    x, y = np.meshgrid(np.arange(0.4, 0.6, 0.002), np.arange(-0.1, 0.1, 0.002))
    surface = np.column_stack([x.ravel(), y.ravel(), 0.2005 + 0.0008 * rng.standard_normal(x.size)])
    centre = np.array([0.5, 0.0, 0.21])
    direction = rng.standard_normal((400, 3))
    direction[:, 2] = np.abs(direction[:, 2])
    sphere = centre + 0.01 * direction / np.linalg.norm(direction, axis=1, keepdims=True)
    finger = np.array([0.45, 0.05, 0.25]) + 0.003 * rng.standard_normal((60, 3))
    cloud = oe.object_cloud_from_scene(np.concatenate([surface, sphere, finger]), config)
    assert cloud.flag is None and len(cloud.points) > 300
    assert np.linalg.norm(cloud.points - centre, axis=1).max() < 0.011  # the sphere alone: no surface, no finger
    assert oe.object_cloud_from_scene(np.concatenate([surface, finger]), config).flag == "no_object_points"
    hidden = oe.object_cloud_from_scene(np.concatenate([surface, sphere, finger]), config, tool_points=sphere)
    assert hidden.points is None and hidden.flag == "hidden_by_tool"


def test_mask_errors_are_seeded_and_bounded():
    mask = np.zeros((60, 80), bool)
    mask[25:37, 30:44] = True
    errors = oe.MaskErrors(wrong_blob=0.5)
    first = [errors.apply(mask, np.random.default_rng(7)) for _ in range(2)]
    np.testing.assert_array_equal(first[0], first[1])
    draws = [errors.apply(mask, np.random.default_rng(s)) for s in range(20)]
    assert any(not np.array_equal(draws[0], d) for d in draws[1:])
    grown = np.zeros_like(mask)
    grown[23:39, 28:46] = True  # dilated by 2 pixels at most: without wrong blobs, nothing lands outside
    no_blobs = [oe.MaskErrors(wrong_blob=0.0).apply(mask, np.random.default_rng(s)) for s in range(20)]
    assert all(not (d & ~grown).any() for d in no_blobs)
    assert any((d & ~grown).any() for d in draws)  # with them, now and then a patch away from the object
    np.testing.assert_array_equal(oe.NO_MASK_ERRORS.apply(mask, np.random.default_rng(0)), mask)
    with pytest.raises(ConfigError):
        oe.MaskErrors(missed=1.0)


def test_temporal_filter_takes_the_median_and_skips_flagged_frames():
    filt = oe.TemporalFilter(window=3)
    assert filt.update(None) is None
    for value in (1.0, 2.0, 100.0):  # one wrong frame is outvoted
        out = filt.update(np.full(3, value))
    np.testing.assert_allclose(out, 2.0)
    np.testing.assert_allclose(filt.update(None), 2.0)
    np.testing.assert_allclose(filt.update(np.full(3, 3.0)), 3.0)  # window: 2, 100, 3
    with pytest.raises(ConfigError):
        oe.estimate_object(None, None, "mean_of_everything")


def test_the_diagnostic_writes_its_tables_and_picture(tmp_path):
    rows, picture = object_estimate_errors.measure(placements=1, frames=2, seed=1, shapes=("cube",), sizes=(0.02,),
                                                   progress=False)
    assert {r["estimator"] for r in rows} == {*oe.ESTIMATORS, *(f"temporal_{n}" for n in oe.ESTIMATORS)}
    summary = object_estimate_errors.summarize(rows)
    path = object_estimate_errors.write_report(rows, summary, picture, tmp_path, "hingelab diagnose test", 1, 2)
    assert {p.name for p in tmp_path.iterdir()} == {"object_estimate.md", "summary.csv", "frames.csv", "frame.png"}
    text = path.read_text()
    assert "| centroid |" in text and "| cube | 2 |" in text
    centroid = next(s for s in summary if s["shape"] == "all" and s["estimator"] == "centroid")
    assert centroid["ray_bias_median_mm"] > 2  # the paper's estimate lies toward the camera
