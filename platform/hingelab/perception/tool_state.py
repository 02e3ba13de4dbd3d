"""``ToolState``: a stream of tool clouds -> the paper's tool state, for B tools at once.

Per control step and per cloud (hand_base, metres):

1. register the cloud to the canonical cloud: after a reset from the nominal in-hand pose
   (with the registration's roll hypotheses), then tracking (``CanonicalRegistration.track``):
   one hypothesis, started at the previous pose moved by part of the last step's motion,
   with a motion prior that holds the roll about the tool's long axis (a single noisy
   frame fixes it only to a few degrees, and differencing would turn that into a large
   omega at rest); a tool whose residual exceeds ``lost_rmse_m`` is registered afresh:
   tool pose t (3,), R (3, 3), Euler angles theta (3,);
2. velocities by differencing consecutive poses over ``dt``: v (3,) m/s, omega (3,) rad/s,
   both in hand_base (omega from R_k R_{k-1}^T); zero on the first step after a reset;
3. move the cloud into the tool frame and encode it: the latent z (2,);
4. exponential moving averages s_bar <- alpha s + (1 - alpha) s_bar (alpha 0.9) of v,
   omega and z (the first step after a reset starts the average at s).

The low level's tool state is ``[v_bar, omega_bar, z_bar]`` (8), the high level's
``[t, theta, z_bar]`` (8). With a calibrated encoder the sample also carries the opening
(rad) and tip gap (mm) read from z_bar.

Usage::

    state = ToolState(n_tools=64)              # the shipped encoder; 64 envs
    state.reset()                              # or reset(mask) for the envs that restarted
    sample = state.update(clouds)              # clouds (64, 256, 3) -> ToolStateSample
    obs_low = sample.low_level()               # (64, 8)
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from hingelab.errors import ConfigError
from hingelab.perception import tool_state_kernels
from hingelab.perception.encoder import ToolEncoder, load_encoder
from hingelab.perception.registration import (
    CanonicalRegistration,
    Registration,
    RegistrationConfig,
    TrackingConfig,
    check_clouds,
    matrix_to_rotvec,
    rotvec_to_matrix,
    tracking_settings,
)
from hingelab.tasks import TOOL_STATE_ALPHA

ALPHA = TOOL_STATE_ALPHA  # the paper's smoothing
CONTROL_DT_S = 0.05  # 20 Hz


@dataclass
class ToolStateSample:
    """One update for B tools (arrays have a leading B axis). Units: m, rad, m/s, rad/s; hand_base."""

    position: np.ndarray  # t (B, 3)
    rotation: np.ndarray  # R (B, 3, 3), tool frame -> hand_base
    euler_xyz: np.ndarray  # theta (B, 3)
    velocity: np.ndarray  # v (B, 3)
    angular_velocity: np.ndarray  # omega (B, 3)
    z: np.ndarray  # (B, 2)
    velocity_smoothed: np.ndarray  # v_bar (B, 3)
    angular_velocity_smoothed: np.ndarray  # omega_bar (B, 3)
    z_smoothed: np.ndarray  # z_bar (B, 2)
    registration_rmse_m: np.ndarray  # (B,)
    calibration: object | None = field(default=None, repr=False)  # the encoder's OpeningCalibration, if any

    # read from z_bar on first use: no env step reads them, and reading both every step costs time
    @functools.cached_property
    def opening_rad(self) -> np.ndarray | None:
        """(B,) opening (rad) read from z_bar, if the encoder is calibrated."""
        return None if self.calibration is None else self.calibration.opening_rad(self.z_smoothed)

    @functools.cached_property
    def tip_gap_mm(self) -> np.ndarray | None:
        """(B,) tip gap (mm) read from z_bar, if the encoder is calibrated."""
        return None if self.calibration is None else self.calibration.tip_gap_mm_for_opening(self.opening_rad)

    def low_level(self) -> np.ndarray:
        """(B, 8): [v_bar, omega_bar, z_bar], the low-level policy's tool state."""
        return np.concatenate([self.velocity_smoothed, self.angular_velocity_smoothed, self.z_smoothed], axis=1)

    def high_level(self) -> np.ndarray:
        """(B, 8): [t, theta, z_bar], the high-level policy's tool state."""
        return np.concatenate([self.position, self.euler_xyz, self.z_smoothed], axis=1)


class ToolState:
    """Turns streams of clouds from ``n_tools`` tools into tool states (see the module docstring).

    Args:
        encoder: a ``ToolEncoder`` (default: the shipped checkpoint, ``load_encoder()``).
        registration: default: a ``CanonicalRegistration`` with the encoder's training config.
        n_tools: how many clouds each ``update`` takes (B).
        alpha: EMA weight of the newest value.
        dt: seconds between updates (the control period).
        prior: (R, t) pose to start registration from after a reset (default: the nominal
            in-hand pose of the ``tool_shape`` grasp); None starts from the global hypotheses.
        lost_rmse_m: a tracked tool with a larger residual (m) is registered afresh.
        tracking: the tracking's motion prior and iterations (``TrackingConfig``).
    """

    def __init__(self, encoder: ToolEncoder | None = None, registration: CanonicalRegistration | None = None,
                 n_tools: int = 1, alpha: float = ALPHA, dt: float = CONTROL_DT_S, prior="nominal",
                 lost_rmse_m: float = 0.006, tracking: TrackingConfig = TrackingConfig()):
        if not 0.0 < alpha <= 1.0 or dt <= 0 or n_tools < 1:
            raise ConfigError(f"ToolState needs 0 < alpha <= 1, dt > 0, n_tools >= 1 (got {alpha}, {dt}, {n_tools})")
        self.encoder = encoder or load_encoder()
        if registration is None:
            config = RegistrationConfig(**(self.encoder.registration_config or {}))
            registration = CanonicalRegistration(config=config)
        self.registration = registration
        self.tracking = tracking
        self.lost_rmse_m = lost_rmse_m
        if isinstance(prior, str) and prior == "nominal":
            # synthetic_dataset brings the episode stack (pandas, pyarrow, mcap) that an env's tracker does not use
            from hingelab.perception.synthetic_dataset import nominal_tool_pose

            prior = nominal_tool_pose()
        self.prior = prior
        self.n_tools, self.alpha, self.dt = n_tools, alpha, dt
        self._rot = np.zeros((n_tools, 3, 3))
        self._pos = np.zeros((n_tools, 3))
        self._motion = np.zeros((n_tools, 6))  # the last step's v, omega: the tracking's prediction
        self._smoothed = np.zeros((n_tools, 8))  # v_bar, omega_bar, z_bar
        self._fresh = np.ones(n_tools, bool)  # no previous pose since the reset
        self._hinge = np.full(n_tools, registration.config.reference_opening_rad)  # last opening estimate

    def reset(self, mask=None) -> None:
        """Forget the history of all tools, or of those where ``mask`` (B,) bool is True."""
        mask = np.ones(self.n_tools, bool) if mask is None else np.asarray(mask, bool)
        if mask.shape != (self.n_tools,):
            raise ConfigError(f"reset mask must have shape ({self.n_tools},), got {mask.shape}")
        self._fresh |= mask

    def _predicted_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The previous poses moved by ``predict_motion`` times the last step's motion: R (B, 3, 3), t (B, 3)."""
        share = self.tracking.predict_motion * self.dt
        turn = rotvec_to_matrix(share * self._motion[:, 3:])
        return turn @ self._rot, self._pos + share * self._motion[:, :3]

    def _register(self, points: np.ndarray, fresh: np.ndarray) -> Registration:
        """Fresh tools from the reset prior (or globally), the others tracked from their predicted pose."""
        if fresh.any():
            start = self.registration.register(points[fresh], prior=self.prior)
            if fresh.all():
                return start
        rot, pos = self._predicted_pose()
        if not fresh.any():
            return self.registration.track(points, rot, pos, self._hinge, self.tracking)
        tracked = self.registration.track(points[~fresh], rot[~fresh], pos[~fresh], self._hinge[~fresh],
                                          self.tracking)
        out = Registration(*(np.empty((len(points),) + getattr(start, f).shape[1:])
                             for f in Registration.__dataclass_fields__))
        for name in Registration.__dataclass_fields__:
            getattr(out, name)[fresh] = getattr(start, name)
            getattr(out, name)[~fresh] = getattr(tracked, name)
        return out

    def update(self, clouds, n_distinct: int | None = None) -> ToolStateSample:
        """Clouds (B, N, 3) (or (N, 3) when n_tools is 1), hand_base metres -> ``ToolStateSample``.

        ``n_distinct``: only the first n_distinct points of each cloud are distinct and the rest
        repeat some of them (the synthesizer's occlusion refill, ``CloudSynthesizer.n_distinct``):
        the encoder reads just those, the same latent (its max pool does not see repeats) for ~20%
        less arithmetic. The registration weighs every point, repeats included.
        """
        points, _ = check_clouds(clouds)
        if n_distinct is not None and not 1 <= n_distinct <= points.shape[1]:
            raise ConfigError(f"n_distinct must be in [1, {points.shape[1]}] (the cloud's points), got {n_distinct}")
        if len(points) != self.n_tools:
            raise ConfigError(f"ToolState was made for {self.n_tools} tools, got {len(points)} clouds")
        n_distinct = points.shape[1] if n_distinct is None else n_distinct
        fresh = self._fresh
        if not fresh.any() and self._compiled_tracking:  # every env step between resets
            step = self._tracked_step(points, n_distinct)
            if step is not None:
                return step
        result = self._register(points, fresh)
        lost = ~fresh & (result.rmse_m > self.lost_rmse_m)
        if lost.any():  # tracking slipped: start those afresh
            again = self._register(points[lost], np.ones(int(lost.sum()), bool))
            for name in ("rotation", "translation", "euler_xyz", "hinge_angle", "rmse_m"):
                getattr(result, name)[lost] = getattr(again, name)
        rot, pos = result.rotation, result.translation
        velocity = np.where(fresh[:, None], 0.0, (pos - self._pos) / self.dt)
        previous = np.where(fresh[:, None, None], rot, self._rot)  # fresh tools: no motion yet
        omega = np.where(fresh[:, None], 0.0, matrix_to_rotvec(rot @ np.swapaxes(previous, 1, 2)) / self.dt)
        z = self.encoder.encode(result.to_tool_frame(points[:, :n_distinct]).astype(np.float32))
        return self._advance(rot, pos, result.euler_xyz, result.hinge_angle, result.rmse_m, velocity, omega, z,
                             fresh=fresh, lost=lost)

    @property
    def _compiled_tracking(self) -> bool:
        """Whether steps between resets can take ``_tracked_step`` (the registration's compiled loops)."""
        return isinstance(self.registration, CanonicalRegistration) and self.registration.compiled

    def _tracked_step(self, points: np.ndarray, n_distinct: int) -> ToolStateSample | None:
        """Steps 1-4 for tools that are all tracked, the arithmetic in one compiled call
        (``tool_state_kernels.tracked_step``) and the encoder; None when a tool needs the general
        path (lost, or an edge case the kernel flags), which then does the whole update."""
        offset, scale = self.encoder.input_offset_and_scale
        rot, pos, theta, rmse, euler, velocity, omega, scaled, redo = tool_state_kernels.tracked_step(
            points, n_distinct, self._rot, self._pos, self._motion, self.tracking.predict_motion * self.dt,
            self._hinge, self.dt, self.lost_rmse_m, offset, scale, *self.registration.tracking_arguments(),
            *tracking_settings(self.tracking))
        if redo.any():
            return None
        theta = theta if self.registration.config.articulated else np.full(self.n_tools, np.nan)
        return self._advance(rot, pos, euler, theta, rmse, velocity, omega, self.encoder.encode_scaled(scaled))

    def _advance(self, rot, pos, euler, theta, rmse, velocity, omega, z, fresh=None, lost=None) -> ToolStateSample:
        """Step 4 and the bookkeeping for the next step. ``fresh`` (B,) bool: tools registered
        after a reset, whose averages start at this state; ``lost`` (B,) bool: tools registered
        afresh after tracking slipped, whose jump is not motion to carry into the next prediction."""
        raw = np.concatenate([velocity, omega, z], axis=1)
        smoothed = self.alpha * raw + (1 - self.alpha) * self._smoothed
        self._smoothed = np.where(fresh[:, None], raw, smoothed) if fresh is not None and fresh.any() else smoothed
        self._motion = np.where(lost[:, None], 0.0, raw[:, :6]) if lost is not None and lost.any() else raw[:, :6]
        self._rot, self._pos, self._fresh = rot, pos, np.zeros(self.n_tools, bool)
        if self.registration.config.articulated:
            self._hinge = theta.copy()
        s = self._smoothed
        return ToolStateSample(pos, rot, euler, velocity, omega, z, s[:, :3].copy(), s[:, 3:6].copy(),
                               s[:, 6:].copy(), rmse, self.encoder.calibration)


__all__ = ["ALPHA", "ToolState", "ToolStateSample"]
