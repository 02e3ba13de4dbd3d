"""Finger targets that hold the tweezer at a given hinge angle: the grasp synergy.

For a hinge angle theta, index and middle (proximal fixed) and the thumb (opposition,
flexion) are placed so that each touches leg b's outer face, pressing ``press`` metres
past it: "each fingertip on the leg, pressing a little past it" (ECOSYSTEM.md). Position
servos then squeeze the leg against the hinge spring, which keeps leg a on the palm.
The table is fitted once by ``scene_builder`` on the settled grasp and stored beside the
scenes; at run time ``FingerSynergy.targets(theta)`` interpolates it. It drives the
hand actuators only: the tool is moved by contact, never by the hinge actuator.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
from scipy.optimize import brentq, least_squares

from hingelab.errors import AssetError
from hingelab.paths import SCENES_DIR
from hingelab.sim import names
from hingelab.sim.hand import HandCoupling

SYNERGY_FILE = SCENES_DIR / "grasp_synergy.json"

# Fixed parts of the grasp posture (radians).
PROXIMAL = 0.8  # index and middle proximal: curled over the tool
PROXIMAL_CHOICES = (0.8, 0.7, 0.6, 0.5, 0.4, 0.3)  # uncurled in turn when leg b opens out of reach
RING_PINKY = 0.6  # resting beside the hinge end
SPREAD = 0.0
THUMB_SLOT_X = 0.084  # metres from the hinge along leg b: centre of the thumb slot


@dataclass(frozen=True)
class FingerSynergy:
    """hinge angle (rad) -> 9 hand actuator targets (rad), by linear interpolation."""

    thetas: np.ndarray  # (K,) increasing
    targets_table: np.ndarray  # (K, 9) in names.HAND_ACTUATORS order

    def targets(self, theta: float) -> np.ndarray:
        """(9,) targets in HAND_ACTUATORS order for hinge angle ``theta`` (clipped to the table)."""
        return np.array([np.interp(theta, self.thetas, col) for col in self.targets_table.T])

    @property
    def theta_range(self) -> tuple[float, float]:
        return float(self.thetas[0]), float(self.thetas[-1])

    def to_json(self) -> dict:
        return {
            "actuators": list(names.HAND_ACTUATORS),
            "thetas": self.thetas.round(5).tolist(),
            "targets": self.targets_table.round(5).tolist(),
        }

    @classmethod
    def load(cls, path: Path = SYNERGY_FILE) -> "FingerSynergy":
        try:
            raw = json.loads(Path(path).read_text())
            thetas = np.asarray(raw["thetas"], float)
            table = np.asarray(raw["targets"], float)
        except FileNotFoundError as exc:
            raise AssetError(
                f"{path} is missing; rebuild the scenes with `python -m hingelab.sim.scene_builder`"
            ) from exc
        except (ValueError, KeyError, TypeError) as exc:
            raise AssetError(
                f"{path} is malformed ({exc}); rebuild it with `python -m hingelab.sim.scene_builder`"
            ) from exc
        if list(raw.get("actuators", [])) != list(names.HAND_ACTUATORS) or table.shape != (len(thetas), 9):
            raise AssetError(f"{path} does not list the 9 SVH actuators; rebuild it with "
                             "`python -m hingelab.sim.scene_builder`")
        return cls(thetas, table)


class SynergyFitter:
    """Solves finger placements on a scene whose tool is already in the hand.

    Works kinematically on a private copy of the data: the tool keeps its pose in the
    hand frame, the hinge and finger joints are set, and geom distances are measured.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData):
        self.model = model
        self.data = mujoco.MjData(model)
        self.data.qpos[:] = data.qpos
        self.qpos0 = data.qpos.copy()
        self.coupling = HandCoupling(model)
        self.leg_b = model.geom("tool_leg_b_geom").id
        self.geoms = {
            "index": [model.geom(f"svh_index_{s}_geom").id for s in "lpt"],
            "middle": [model.geom(f"svh_middle_{s}_geom").id for s in "kos"],
            "thumb": [model.geom("svh_thumb_c_geom").id],
        }
        self._fromto = np.zeros(6)

    def _pose(self, theta: float, primary: dict[str, float]) -> None:
        d = self.data
        d.qpos[:] = self.qpos0
        d.joint(names.TOOL_HINGE).qpos = theta
        for joint, value in primary.items():
            d.joint(joint).qpos = value
        self.coupling.apply_to_qpos(d)
        mujoco.mj_kinematics(self.model, d)

    def _distance(self, finger: str) -> float:
        return min(
            mujoco.mj_geomDistance(self.model, self.data, g, self.leg_b, 0.05, self._fromto)
            for g in self.geoms[finger]
        )

    def finger_distal(self, theta: float, finger: str, press: float,
                      proximal: float = PROXIMAL) -> float | None:
        """Distal angle at which ``finger`` presses ``press`` m into leg b, or None if out of reach."""
        def gap(distal: float) -> float:
            self._pose(theta, {f"svh_{finger}_proximal": proximal, f"svh_{finger}_distal": distal})
            return self._distance(finger) + press

        # the first contact as the finger curls: scan, then refine the first sign change
        # (the gap is not monotonic: a fully curled tip can pass beside the leg)
        lo, hi = self.model.joint(f"svh_{finger}_distal").range
        grid = np.linspace(lo, hi, 28)
        gaps = [gap(x) for x in grid]
        for k in range(len(grid) - 1):
            if gaps[k] > 0 >= gaps[k + 1]:
                return brentq(gap, grid[k], grid[k + 1], xtol=1e-4)
        return None

    def finger(self, theta: float, finger: str, press: float) -> tuple[float, float] | None:
        """(proximal, distal) pressing leg b: the most curled proximal from which the tip reaches."""
        for proximal in PROXIMAL_CHOICES:
            distal = self.finger_distal(theta, finger, press, proximal)
            if distal is not None:
                return proximal, distal
        return None

    def thumb(self, theta: float, press: float, start: tuple[float, float]) -> tuple[float, float]:
        """(opposition, flexion) with the thumb tip in the slot, pressing ``press`` m into leg b."""
        d = self.data

        def residual(x):
            self._pose(theta, {"svh_thumb_opposition": x[0], "svh_thumb_flexion": x[1]})
            hb = d.body(names.HAND_BASE_BODY)
            rot_h = hb.xmat.reshape(3, 3)
            tip = rot_h.T @ (d.site("svh_thumb_tip").xpos - hb.xpos)
            leg = d.body(names.TOOL_BODY_B)
            slot = rot_h.T @ (leg.xpos + leg.xmat.reshape(3, 3) @ [THUMB_SLOT_X, 0.006, 0] - hb.xpos)
            return [(self._distance("thumb") + press) * 100, (tip[0] - slot[0]) * 30]

        lo = [self.model.joint("svh_thumb_opposition").range[0], self.model.joint("svh_thumb_flexion").range[0]]
        hi = [self.model.joint("svh_thumb_opposition").range[1], self.model.joint("svh_thumb_flexion").range[1]]
        sol = least_squares(residual, start, bounds=(lo, hi))
        return float(sol.x[0]), float(sol.x[1])

    def fit(self, thetas: np.ndarray, press: float = 0.002) -> FingerSynergy:
        rows = []
        thumb = (0.0, 0.33)
        kept = []
        for theta in thetas:
            index = self.finger(theta, "index", press)
            middle = self.finger(theta, "middle", press)
            if index is None or middle is None:
                continue  # beyond the fingers' reach: the table ends here
            thumb = self.thumb(theta, press, thumb)
            target = {
                "svh_thumb_flexion": thumb[1], "svh_thumb_opposition": thumb[0],
                "svh_index_distal": index[1], "svh_index_proximal": index[0],
                "svh_middle_distal": middle[1], "svh_middle_proximal": middle[0],
                "svh_ring": RING_PINKY, "svh_pinky": RING_PINKY, "svh_spread": SPREAD,
            }
            rows.append([target[a] for a in names.HAND_ACTUATORS])
            kept.append(theta)
        if len(kept) < 2:
            raise AssetError("the fingers cannot reach leg b over the hinge range: check the grasp pose")
        return FingerSynergy(np.asarray(kept), np.asarray(rows))
