"""The object's known model fitted to its visible points (``mesh_fit``): on rendered frames of the stand-in's
objects it lands within a millimetre or two of the true centre where the visible-points estimators lie toward
the camera, it holds a resting object at its support, and without a model it says what it needs."""

from __future__ import annotations

import numpy as np
import pytest

from hingelab.camera import AZURE_KINECT_NFOV_UNBINNED as RIG
from hingelab.errors import ConfigError
from hingelab.perception import object_estimate as oe
from hingelab.perception.object_model_fit import ObjectModel, fit_model
from hingelab.perception.object_perception import SUPPORT_ERROR_M, CameraObjectEstimate
from hingelab.ros2.object_from_cloud import check_estimator
from hingelab.sim import scripted
from hingelab.sim.core import SimCore
from hingelab.sim.depth_noise import DepthNoise
from hingelab.sim.object_render import ObjectDepthRenderer, platform_crop, true_object_centre
from hingelab.sim.objects import ObjectSpec


def frames(shape: str, size: float, spots: int, seed: int):
    """(visible points, camera position, truth, model) at ``spots`` random spots, with depth noise and mask
    errors (no wrong blob)."""
    obj = ObjectSpec(shape, size)
    sim = SimCore("tool_pick", obj=obj, camera=RIG)
    renderer = ObjectDepthRenderer(sim.model, RIG)
    config = oe.ObjectCloudConfig(*platform_crop(sim.model))
    model = ObjectModel.from_mujoco(sim.model)
    rng = np.random.default_rng(seed)
    out = []
    try:
        for _ in range(spots):
            sim.reset(seed=int(rng.integers(2**31)),
                      object_xy=scripted.platform_center(sim.model) + rng.uniform(-0.05, 0.05, 2))
            rendered = renderer.render(sim.data)
            frame = rendered.frame
            frame.depth = DepthNoise().apply(frame.depth, RIG, rng)
            cloud = oe.object_cloud(frame, oe.MaskErrors(wrong_blob=0.0).apply(rendered.object_mask, rng), config)
            out.append((cloud.points, np.asarray(frame.camera_position, float),
                        true_object_centre(sim.model, sim.data, obj), model))
    finally:
        renderer.close()
    return out


@pytest.mark.parametrize("shape", ["sphere", "cube", "tetrahedron"])
def test_the_model_fit_lands_near_the_true_centre(shape):
    for points, camera, truth, model in frames(shape, 0.02, spots=3, seed=7):
        fitted = oe.mesh_fit(points, camera, model)
        rough = oe.ray_corrected(points, camera)
        assert np.linalg.norm(fitted - truth) < 0.0025, (shape, 1000 * (fitted - truth))
        if shape == "sphere":  # ray_corrected lies 4 to 5 mm toward the camera on the 2 cm sphere
            assert np.linalg.norm(fitted - truth) < np.linalg.norm(rough - truth) - 0.002


def test_a_resting_fit_sits_on_the_support_and_a_lifted_object_keeps_its_height():
    (points, camera, truth, model), = frames("cube", 0.02, spots=1, seed=3)
    resting = fit_model(points, camera, model, oe.ray_corrected(points, camera))
    assert model.support_z is not None
    assert resting.translation[2] + model.bottom == pytest.approx(model.support_z, abs=1e-9)
    lifted = points + np.array([0.0, 0.0, 0.03])  # the same points 3 cm up: the support cannot hold it
    fit = fit_model(lifted, camera, model, oe.ray_corrected(lifted, camera))
    assert abs(fit.centre[2] - (truth[2] + 0.03)) < 0.003


def test_the_model_sample_spans_the_object():
    (_, _, _, model), = frames("tetrahedron", 0.02, spots=1, seed=0)
    height = ObjectSpec("tetrahedron", 0.02).height
    assert model.points.shape == model.normals.shape and len(model.points) > 500
    np.testing.assert_allclose(np.linalg.norm(model.normals, axis=1), 1.0, atol=1e-9)
    assert model.centre[2] == pytest.approx(model.bottom + height / 2, abs=1e-6)


def test_without_a_model_mesh_fit_says_what_it_needs():
    points = np.random.default_rng(0).normal(size=(50, 3)) * 0.005
    with pytest.raises(ConfigError, match="needs the object's model"):
        oe.mesh_fit(points, np.array([0.5, 0.0, 0.5]))
    with pytest.raises(ConfigError, match="a bag does not carry"):
        check_estimator("mesh_fit")


def test_the_platform_height_the_fit_rests_on_is_off_by_a_seeded_draw_within_its_bound():
    sim = SimCore("tool_pick", obj=ObjectSpec("cube", 0.02), camera=RIG)
    exact = ObjectModel.from_mujoco(sim.model).support_z
    camera = CameraObjectEstimate("mesh_fit")
    draws = []
    for seed in range(20):
        camera.new_episode(seed, sim.model)
        draws.append(camera.object_model.support_z - exact)
        assert camera.support_error == pytest.approx(draws[-1])
    assert max(abs(d) for d in draws) <= SUPPORT_ERROR_M and np.std(draws) > SUPPORT_ERROR_M / 4
    camera.new_episode(3, sim.model)
    assert camera.support_error == pytest.approx(draws[3])  # the seed's own draw
    other = CameraObjectEstimate("ray_corrected")
    other.new_episode(3, sim.model)
    assert other.object_model is None and other.support_error == 0.0
    with pytest.raises(ConfigError, match="support height"):
        CameraObjectEstimate("mesh_fit", support_error_m=-0.001)
