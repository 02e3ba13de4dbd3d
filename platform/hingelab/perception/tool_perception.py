"""The tool as the policies see it: a cloud per step through ``ToolState``.

One object per env: where the clouds come from, and the tool-state tracker (registration,
differencing, encoder, EMA). Two sources (``perception=``):

* ``"synthesized"`` (the default, the paper's training clouds): ``CloudSynthesizer`` samples
  the tool's model surface at its simulated pose (realism on, its per-episode pose error
  drawn at reset);
* ``"camera"``: the rig's depth camera rendered by MuJoCo (``hingelab.sim.depth_render``),
  made noisy (``hingelab.sim.depth_noise``) and turned into the tool's cloud by the camera
  cloud pipeline (``hingelab.perception.camera_cloud``), as on the real rig. The sim must have
  been built with the camera (``SimCore(camera=intrinsics)``).

A camera frame that gives no usable cloud (no returns, the tool out of view) sets
``flag`` for that step; the tracker is then fed the last good cloud (or, right after a
reset, the canonical cloud at the nominal in-hand pose), and the env ends the episode.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from hingelab.camera import AZURE_KINECT_NFOV_UNBINNED, CameraFrame, DepthIntrinsics
from hingelab.errors import ConfigError
from hingelab.perception.camera_cloud import ToolCloud, ToolCloudConfig, tool_cloud_from_frame
from hingelab.perception.clouds import IDEAL, N_POINTS, CloudRealism, CloudSynthesizer
from hingelab.perception.encoder import ToolEncoder, load_encoder
from hingelab.perception.hand_eye import Alignment, corrected_pose, refine_on_frame
from hingelab.perception.tool_state import ALPHA, ToolState, ToolStateSample
from hingelab.sim.core import SimCore
from hingelab.sim.depth_noise import DepthNoise
from hingelab.sim.depth_render import DepthRenderer

PERCEPTIONS = ("synthesized", "camera")


def check_perception(perception: str) -> str:
    if perception not in PERCEPTIONS:
        raise ConfigError(f"perception {perception!r} is unknown; choose one of {', '.join(PERCEPTIONS)}")
    return perception


def camera_for(perception: str) -> DepthIntrinsics | None:
    """The camera a ``SimCore`` needs for ``perception`` (None: no camera)."""
    return AZURE_KINECT_NFOV_UNBINNED if check_perception(perception) == "camera" else None


class SynthesizedClouds:
    """Clouds sampled from the tool's model at its simulated pose (``CloudSynthesizer``)."""

    def __init__(self, realistic: bool = True):
        self.synthesizer = CloudSynthesizer(realism=CloudRealism() if realistic else IDEAL)

    def new_episode(self, seed: int | None) -> None:
        self.synthesizer.new_episode(seed)

    def cloud(self, sim: SimCore) -> ToolCloud:
        return ToolCloud(self.synthesizer.from_sim(sim.model, sim.data), self.synthesizer.n_distinct)


EXTRINSIC_ERROR_M = 0.003  # per axis, uniform: a hand-eye calibration's error (chosen, not measured)
EXTRINSIC_ERROR_RAD = float(np.radians(1.0))  # per axis, uniform
CALIBRATED, REFINED, EXACT = "calibrated", "refined", "exact"
# the camera pose as calibrated (with its error), refined on the robot's own points each episode, or the true pose
# (a diagnostic only a simulator can run: what the calibration error costs)
HAND_EYE = (CALIBRATED, REFINED, EXACT)


def check_hand_eye(value: str) -> str:
    if value not in HAND_EYE:
        raise ConfigError(f"hand-eye {value!r} is unknown; choose {', '.join(HAND_EYE[:-1])} or {HAND_EYE[-1]}")
    return value


class CameraClouds:
    """Clouds from the rendered depth camera through the camera cloud pipeline; ``frame`` is the last frame
    (noisy, posed where the calibration believes the camera is) and ``geoms`` its pixels' geom ids, which the
    object's estimate (``hingelab.perception.object_perception``) reads instead of rendering again.

    The pipeline places the points with the camera pose it believes: the true one moved by a
    per-episode calibration error (up to ``EXTRINSIC_ERROR_M`` and ``EXTRINSIC_ERROR_RAD`` per axis),
    as a rig's hand-eye calibration is off by a few millimetres and about a degree.

    ``hand_eye="exact"``: the true pose (the error is drawn, so the other draws stay, and not applied).
    ``hand_eye="refined"``: on an episode's first frame the believed pose is corrected by aligning the robot's
    own points in the depth image with its model (``hingelab.perception.hand_eye``), and every frame of the
    episode uses the corrected pose; ``refinement`` holds that alignment (None: not refined, or too few
    robot points, when the pose stays as calibrated)."""

    def __init__(self, intrinsics: DepthIntrinsics = AZURE_KINECT_NFOV_UNBINNED, noise: DepthNoise = DepthNoise(),
                 config: ToolCloudConfig = ToolCloudConfig(), extrinsic_error: tuple[float, float] = (
                     EXTRINSIC_ERROR_M, EXTRINSIC_ERROR_RAD), hand_eye: str = CALIBRATED):
        self.intrinsics, self.noise, self.config = intrinsics, noise, config
        self.extrinsic_error = extrinsic_error
        self.hand_eye = check_hand_eye(hand_eye)
        self.refinement: Alignment | None = None
        self._refine_rng = np.random.default_rng()
        self._refined = False
        self.renderer = None  # made on the first frame, from the sim's model
        self.rng = np.random.default_rng()
        self._error_rot, self._error_pos = np.eye(3), np.zeros(3)
        self.frame: CameraFrame | None = None
        self.geoms: np.ndarray | None = None  # (H, W) the last frame's geom id per pixel (-1: none), for the object
        self.result: ToolCloud | None = None

    def new_episode(self, seed: int | None) -> None:
        # its own stream: the camera's noise does not shift the env's other draws
        self.rng = np.random.default_rng(None if seed is None else [seed, 28])
        offset, angle = self.extrinsic_error
        self._error_pos = self.rng.uniform(-offset, offset, 3)
        self._error_rot = Rotation.from_euler("xyz", self.rng.uniform(-angle, angle, 3)).as_matrix()
        self._refine_rng = np.random.default_rng(None if seed is None else [seed, 45])  # its own: no draw shifts
        self.refinement, self._refined = None, False

    def cloud(self, sim: SimCore) -> ToolCloud:
        if self.renderer is None:
            self.renderer = DepthRenderer(sim.model, self.intrinsics)
        depth, self.geoms = self.renderer.depth_and_geoms(sim.data)
        frame = self.renderer.frame_from(sim.data, depth, self.geoms, stamp_s=float(sim.data.time))
        frame.depth = self.noise.apply(frame.depth, self.intrinsics, self.rng)
        if self.hand_eye != EXACT:
            frame.camera_rotation = self._error_rot @ frame.camera_rotation  # the believed pose (calibration error)
            frame.camera_position = frame.camera_position + self._error_pos
        if self.hand_eye == REFINED:
            if not self._refined:  # the episode's first frame: measure the correction once
                self.refinement = refine_on_frame(self.renderer, sim.data, frame, self.geoms, self._refine_rng)
                self._refined = True
            if self.refinement is not None:
                frame.camera_rotation, frame.camera_position = corrected_pose(
                    self.refinement, frame.camera_rotation, frame.camera_position)
        self.frame = frame
        self.result = tool_cloud_from_frame(frame, self.config, self.rng)
        return self.result

    def close(self) -> None:
        if self.renderer is not None:
            self.renderer.close()
            self.renderer = None


class ToolPerception:
    """``reset(seed)`` then ``observe(sim) -> ToolStateSample`` (B = 1) once per control step."""

    def __init__(self, encoder: ToolEncoder | None = None, realistic: bool = True, dt: float = 0.05,
                 alpha: float = ALPHA, perception: str = "synthesized", hand_eye: str = CALIBRATED):
        self.encoder = encoder or load_encoder()
        self.perception = check_perception(perception)
        if check_hand_eye(hand_eye) != CALIBRATED and perception != "camera":
            raise ConfigError(f"hand-eye {hand_eye!r} refines the depth camera's pose: it needs perception 'camera' "
                              f"(--perception camera), not {perception!r}")
        self.source = SynthesizedClouds(realistic) if perception == "synthesized" else CameraClouds(hand_eye=hand_eye)
        self.tool_state = ToolState(encoder=self.encoder, n_tools=1, dt=dt, alpha=alpha)
        self.cloud: np.ndarray | None = None  # (256, 3) float32, hand_base: the last cloud
        self.flag: str | None = None  # why this step's frame gave no cloud (camera perception)

    @property
    def synthesizer(self) -> CloudSynthesizer | None:
        return getattr(self.source, "synthesizer", None)

    @property
    def camera(self) -> CameraClouds | None:
        return self.source if isinstance(self.source, CameraClouds) else None

    def reset(self, seed: int | None) -> None:
        self.source.new_episode(seed)
        self.tool_state.reset()
        self.cloud = None

    def observe(self, sim: SimCore) -> ToolStateSample:
        result = self.source.cloud(sim)
        self.flag = result.flag
        if result.points is None:
            points = self.cloud if self.cloud is not None else self._nominal_cloud()
            return self.tool_state.update(points[None])
        self.cloud = result.points
        return self.tool_state.update(self.cloud[None], n_distinct=result.n_distinct)

    def _nominal_cloud(self) -> np.ndarray:
        """The canonical cloud at the tracker's nominal in-hand pose: what the tracker assumes before a frame."""
        rot, pos = self.tool_state.prior
        canonical = self.tool_state.registration.canonical
        index = np.linspace(0, len(canonical) - 1, N_POINTS).astype(int)
        return (canonical[index] @ np.asarray(rot).T + np.asarray(pos)).astype(np.float32)

    def close(self) -> None:
        if isinstance(self.source, CameraClouds):
            self.source.close()

    @property
    def calibration(self):
        return self.encoder.calibration
