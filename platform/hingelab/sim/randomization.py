"""Domain randomization, sampled once per episode (paper, "Simulated Experiments").

Control gains 60% to 150% of nominal (hand position servos, and the arm's when it is
present), sliding friction 0.2 to 1 per finger segment and tweezer part, object friction
1 to 5, observation delays up to 150 ms. MuJoCo combines two geoms' friction by the
maximum, so a contact is as slippery as its grippier side allows.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from hingelab.sim import names


@dataclass(frozen=True)
class RandomizationConfig:
    enabled: bool = True
    gain_range: tuple[float, float] = (0.6, 1.5)
    finger_friction_range: tuple[float, float] = (0.2, 1.0)
    object_friction_range: tuple[float, float] = (1.0, 5.0)
    max_observation_delay_s: float = 0.150


@dataclass(frozen=True)
class EpisodeRandomization:
    """What was drawn for one episode (logged with it)."""

    gain_scale: np.ndarray  # (n_actuators,) per actuator
    geom_friction: np.ndarray  # (n_geoms,) sliding friction of the randomized geoms
    object_friction: float
    observation_delay_s: float


class DomainRandomizer:
    """Applies a sampled ``EpisodeRandomization`` to the model in place, and undoes it."""

    def __init__(self, model: mujoco.MjModel, config: RandomizationConfig):
        self.model = model
        self.config = config
        self.nominal_gain = model.actuator_gainprm[:, 0].copy()
        self.nominal_bias = model.actuator_biasprm[:, :3].copy()
        self.nominal_friction = model.geom_friction[:, 0].copy()
        self.actuators = np.array([model.actuator(a).id for a in names.HAND_ACTUATORS + names.ARM_ACTUATORS
                                   if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a) >= 0])
        body_names = [model.body(model.geom_bodyid[g]).name for g in range(model.ngeom)]
        self.finger_geoms = np.array([g for g, b in enumerate(body_names)
                                      if b.startswith("svh_") or b.startswith("tool_")], dtype=int)
        self.object_geoms = np.array([g for g, b in enumerate(body_names) if b == names.OBJECT_BODY], dtype=int)

    def sample(self, rng: np.random.Generator) -> EpisodeRandomization:
        c = self.config
        if not c.enabled:
            return EpisodeRandomization(np.ones(len(self.actuators)), self.nominal_friction[self.finger_geoms].copy(),
                                        float(self.nominal_friction[self.object_geoms][0])
                                        if len(self.object_geoms) else 1.0,
                                        0.0)
        return EpisodeRandomization(
            gain_scale=rng.uniform(*c.gain_range, size=len(self.actuators)),
            geom_friction=rng.uniform(*c.finger_friction_range, size=len(self.finger_geoms)),
            object_friction=float(rng.uniform(*c.object_friction_range)),
            observation_delay_s=float(rng.uniform(0.0, c.max_observation_delay_s)),
        )

    def apply(self, episode: EpisodeRandomization) -> None:
        m = self.model
        self.restore()
        a = self.actuators
        # position servo: force = kp * ctrl - kp * q - kv * qdot; scale kp and kv together
        m.actuator_gainprm[a, 0] = self.nominal_gain[a] * episode.gain_scale
        m.actuator_biasprm[a, 1] = self.nominal_bias[a, 1] * episode.gain_scale
        m.actuator_biasprm[a, 2] = self.nominal_bias[a, 2] * episode.gain_scale
        m.geom_friction[self.finger_geoms, 0] = episode.geom_friction
        if len(self.object_geoms):
            m.geom_friction[self.object_geoms, 0] = episode.object_friction

    def restore(self) -> None:
        m = self.model
        m.actuator_gainprm[:, 0] = self.nominal_gain
        m.actuator_biasprm[:, :3] = self.nominal_bias
        m.geom_friction[:, 0] = self.nominal_friction
