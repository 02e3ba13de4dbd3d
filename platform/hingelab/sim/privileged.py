"""The privileged simulator state: what the simulator knows and a real robot would not.

Frames: ``*_hand`` quantities are in the ``hand_base`` frame (metres, unit quaternions
w x y z); ``*_world`` in the world (= arm base) frame. The tool frame is ``tool_leg_a``'s:
origin on the hinge axis, +x toward the tips.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import mujoco
import numpy as np
from numba import njit

from hingelab.sim import names

# geom categories for contact bookkeeping
OTHER, ARM, HAND, TOOL, OBJECT, TABLE = range(6)


@dataclass(frozen=True)
class PrivilegedState:
    time: float  # s, simulated
    hinge_angle: float  # rad, 0 = closed
    tool_pos_hand: np.ndarray  # (3,) tool frame origin in hand_base
    tool_quat_hand: np.ndarray  # (4,) w x y z
    tip_a_hand: np.ndarray  # (3,) inner tip face of leg a
    tip_b_hand: np.ndarray  # (3,)
    tip_gap: float  # m, distance between the tip sites
    hand_pos_world: np.ndarray  # (3,)
    hand_quat_world: np.ndarray  # (4,)
    object_pos_world: np.ndarray  # (3,) NaN in scenes without an object
    object_quat_world: np.ndarray  # (4,)
    object_pos_hand: np.ndarray  # (3,)
    n_contacts: int  # all active contacts
    hand_tool_contacts: int
    tool_object_contacts: int
    table_collision: bool  # arm, hand or tool touching the table or the platform

    def as_dict(self) -> dict:
        """Plain dict of floats / lists (for logging)."""
        out = {}
        for key, value in asdict(self).items():
            out[key] = value.tolist() if isinstance(value, np.ndarray) else value
        return out


@njit(cache=True)
def _count_contacts(geom_pairs, category):
    """(hand-tool contacts, tool-object contacts, any arm/hand/tool-table contact) of (n, 2) geom ids."""
    hand_tool = tool_object = 0
    table = False
    for i in range(geom_pairs.shape[0]):
        a, b = category[geom_pairs[i, 0]], category[geom_pairs[i, 1]]
        low, high = min(a, b), max(a, b)
        if low == HAND and high == TOOL:
            hand_tool += 1
        elif low == TOOL and high == OBJECT:
            tool_object += 1
        elif high == TABLE and (low == ARM or low == HAND or low == TOOL):
            table = True
    return hand_tool, tool_object, table


@njit(cache=True)
def _hand_frame_points(xpos, xmat, site_xpos, hand_body, tool_body, tip_a_site, tip_b_site, object_body):
    """Points in the hand_base frame (m), compiled: one call instead of ~20 small numpy ops per step.

    Returns ((4, 3) rows: tool frame origin, tip a, tip b, object origin (NaN without an
    object); the tip gap, m). ``xpos``/``site_xpos``: MjData's (n, 3) world positions,
    ``xmat``: its (nbody, 9) row-major world rotations. Each point is ``R_hand^T (p - p_hand)``
    summed in index order, the same rounding as numpy's ``rot.T @ (p - pos)`` (checked bit for
    bit); a 3x3 @ 3x3 product would not match numpy's and stays out of here.
    """
    out = np.empty((4, 3))
    sources = ((xpos, tool_body), (site_xpos, tip_a_site), (site_xpos, tip_b_site), (xpos, object_body))
    for row in range(4):
        positions, index = sources[row]
        if index < 0:
            out[row, :] = np.nan
            continue
        d0 = positions[index, 0] - xpos[hand_body, 0]
        d1 = positions[index, 1] - xpos[hand_body, 1]
        d2 = positions[index, 2] - xpos[hand_body, 2]
        for i in range(3):  # column i of the hand rotation = hand axis i in the world
            out[row, i] = xmat[hand_body, i] * d0 + xmat[hand_body, 3 + i] * d1 + xmat[hand_body, 6 + i] * d2
    g0, g1, g2 = out[1, 0] - out[2, 0], out[1, 1] - out[2, 1], out[1, 2] - out[2, 2]
    return out, np.sqrt(g0 * g0 + g1 * g1 + g2 * g2)


class PrivilegedReader:
    """Reads ``PrivilegedState`` from MjData; the by-name lookups are done once here."""

    def __init__(self, model: mujoco.MjModel):
        self.model = model
        self.hand_body = model.body(names.HAND_BASE_BODY).id
        self.tool_body = model.body(names.TOOL_BODY_A).id
        self.tips = [model.site(s).id for s in names.TOOL_TIP_SITES]
        self.hinge_qpos = model.jnt_qposadr[model.joint(names.TOOL_HINGE).id]
        self.object_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, names.OBJECT_BODY)
        self.geom_category = self._categorize(model)

    def _categorize(self, model: mujoco.MjModel) -> np.ndarray:
        category = np.full(model.ngeom, OTHER, dtype=np.int8)
        for g in range(model.ngeom):
            geom_name = model.geom(g).name
            body_name = model.body(model.geom_bodyid[g]).name
            if geom_name in names.TABLE_GEOMS:
                category[g] = TABLE
            elif body_name.startswith("arm_"):
                category[g] = ARM
            elif body_name.startswith("svh_") or body_name == names.HAND_BASE_BODY:
                category[g] = HAND
            elif body_name.startswith("tool_"):
                category[g] = TOOL
            elif body_name == names.OBJECT_BODY:
                category[g] = OBJECT
        return category

    def contact_counts(self, data: mujoco.MjData) -> tuple[int, int, int, bool]:
        n = data.ncon
        if n == 0:
            return 0, 0, 0, False
        # compiled: read every control step (a numpy bincount costs several times more)
        hand_tool, tool_object, table = _count_contacts(data.contact.geom[:n], self.geom_category)
        return n, int(hand_tool), int(tool_object), bool(table)

    def read(self, data: mujoco.MjData) -> PrivilegedState:
        xpos, xquat = data.xpos, data.xquat  # each MjData attribute read builds a new view: once each
        rot_h = data.xmat[self.hand_body].reshape(3, 3)
        # numpy's matmul here: its rounding is the reference the tool quaternion is compared to
        tool_rot = rot_h.T @ data.xmat[self.tool_body].reshape(3, 3)
        tool_quat = np.zeros(4)
        mujoco.mju_mat2Quat(tool_quat, tool_rot.ravel())
        points, tip_gap = _hand_frame_points(xpos, data.xmat, data.site_xpos, self.hand_body, self.tool_body,
                                             self.tips[0], self.tips[1], self.object_body)
        tool_pos, tip_a, tip_b, obj_hand = points  # rows: (3,) views, one fresh buffer per state
        if self.object_body >= 0:
            obj_pos = xpos[self.object_body].copy()
            obj_quat = xquat[self.object_body].copy()
        else:
            obj_pos = np.full(3, np.nan)
            obj_quat = np.full(4, np.nan)
        n, hand_tool, tool_obj, table = self.contact_counts(data)
        return PrivilegedState(
            time=float(data.time),
            hinge_angle=float(data.qpos[self.hinge_qpos]),
            tool_pos_hand=tool_pos,
            tool_quat_hand=tool_quat,
            tip_a_hand=tip_a,
            tip_b_hand=tip_b,
            tip_gap=float(tip_gap),
            hand_pos_world=xpos[self.hand_body].copy(),
            hand_quat_world=xquat[self.hand_body].copy(),
            object_pos_world=obj_pos,
            object_quat_world=obj_quat,
            object_pos_hand=obj_hand,
            n_contacts=n,
            hand_tool_contacts=hand_tool,
            tool_object_contacts=tool_obj,
            table_collision=table,
        )
