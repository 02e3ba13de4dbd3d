"""The camera's sim-to-real gap on the perception itself: camera clouds against synthesized ones, same poses.

One simulated hand (``tool_shape``, randomization on) holds the tweezer while its fingers
open and close it along the grasp synergy (a sine between the reachable ends, a period and
phase drawn per episode). Every control step both perceptions see the same simulated state:

* ``synthesized``: ``CloudSynthesizer`` (the paper's realism: 3 mm noise, 20% removal, the
  per-episode pose error), through its own ``ToolState``;
* ``camera``: the rendered depth frame, its noise model and the camera cloud pipeline,
  through another ``ToolState``.

Per step and perception: the opening read from the latent (the encoder's calibration reader)
against the true hinge angle, and the tracked tool pose against the privileged one (position
error in mm, rotation error in degrees). ``summarize`` gives the opening R^2 and error, the
tracking errors' medians and 95th percentiles, and the share of camera frames that gave no
cloud. ``hingelab eval perception`` runs it and draws the picture of one frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import pandas as pd
from tqdm import tqdm

from hingelab.perception.calibration import r_squared
from hingelab.perception.encoder import load_encoder
from hingelab.perception.tool_perception import ToolPerception, camera_for
from hingelab.seeds import demo_seed
from hingelab.sim.core import SimCore
from hingelab.sim.finger_synergy import FingerSynergy
from hingelab.sim.randomization import RandomizationConfig

PERCEPTIONS = ("synthesized", "camera")


@dataclass(frozen=True)
class GapConfig:
    episodes: int = 8
    steps: int = 100  # control steps per episode (5 s)
    seed: int = 0
    warmup_steps: int = 5  # steps after a reset not scored (the trackers' averages start)


def _rotation_error_deg(r_est: np.ndarray, r_true: np.ndarray) -> float:
    cos = (np.trace(r_est.T @ r_true) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def run_gap(config: GapConfig = GapConfig(), progress: bool = True, frame_hook=None) -> pd.DataFrame:
    """One row per scored step and perception: episode, step, perception, opening_true_rad,
    opening_est_rad, z0, z1, position_error_mm, rotation_error_deg, flag.

    ``frame_hook(episode, step, sim, perceptions)`` is called after every observation (the picture uses it)."""
    sim = SimCore("tool_shape", randomization=RandomizationConfig(enabled=True), camera=camera_for("camera"))
    encoder = load_encoder()
    perceptions = {name: ToolPerception(encoder, dt=sim.control_dt, perception=name) for name in PERCEPTIONS}
    synergy = FingerSynergy.load()
    low, high = synergy.theta_range
    rows = []
    bar = tqdm(total=config.episodes * config.steps, desc="perception gap", unit="step", disable=not progress)
    try:
        for episode in range(config.episodes):
            seed = demo_seed(config.seed, episode)
            rng = np.random.default_rng(seed)
            period = rng.uniform(40, 80)  # steps per open-close cycle
            phase = rng.uniform(0, 2 * np.pi)
            state = sim.reset(seed=seed)
            for p in perceptions.values():
                p.reset(seed)
            for step in range(config.steps):
                theta = low + (high - low) * 0.5 * (1 + np.sin(2 * np.pi * step / period + phase))
                sim.set_hand_targets(synergy.targets(theta))
                if step > 0:
                    state = sim.step().state
                samples = {name: p.observe(sim) for name, p in perceptions.items()}
                if frame_hook is not None:
                    frame_hook(episode, step, sim, perceptions)
                bar.update()
                if step < config.warmup_steps:
                    continue
                rot_true = np.zeros(9)
                mujoco.mju_quat2Mat(rot_true, state.tool_quat_hand)
                for name, s in samples.items():
                    rows.append({
                        "episode": episode, "step": step, "perception": name,
                        "opening_true_rad": state.hinge_angle,
                        "opening_est_rad": float(s.opening_rad[0]),
                        "z0": float(s.z[0, 0]), "z1": float(s.z[0, 1]),
                        "position_error_mm": 1000 * float(np.linalg.norm(s.position[0] - state.tool_pos_hand)),
                        "rotation_error_deg": _rotation_error_deg(s.rotation[0], rot_true.reshape(3, 3)),
                        "flag": perceptions[name].flag or "",
                    })
    finally:
        bar.close()
        for p in perceptions.values():
            p.close()
    return pd.DataFrame(rows)


def summarize(rows: pd.DataFrame) -> pd.DataFrame:
    """Per perception: opening R^2 and mean absolute error, tracking error medians and 95th percentiles, flagged
    share."""
    out = []
    for name, g in rows.groupby("perception", sort=False):
        ok = g[g["flag"] == ""]
        out.append({
            "perception": name, "steps": len(g), "flagged_share": 1 - len(ok) / max(len(g), 1),
            "opening_r2": r_squared(ok["opening_true_rad"].to_numpy(), ok["opening_est_rad"].to_numpy()),
            "opening_mae_mrad": 1000 * float((ok["opening_est_rad"] - ok["opening_true_rad"]).abs().mean()),
            "position_error_mm_median": float(ok["position_error_mm"].median()),
            "position_error_mm_p95": float(ok["position_error_mm"].quantile(0.95)),
            "rotation_error_deg_median": float(ok["rotation_error_deg"].median()),
            "rotation_error_deg_p95": float(ok["rotation_error_deg"].quantile(0.95)),
        })
    return pd.DataFrame(out)
