"""The model's public names: every later module and outside tool uses these.

Code reads state by name (``data.joint("tool_hinge").qpos``), never by qpos slices.
"""

ARM_JOINTS = tuple(f"arm_joint_{i}" for i in range(1, 7))
ARM_ACTUATORS = ARM_JOINTS  # one position servo per joint, same names

# The 9 SVH motor channels, in the real driver's channel order. Each drives the
# primary joint of the same name; the 11 coupled joints follow by equality constraints.
HAND_ACTUATORS = (
    "svh_thumb_flexion",
    "svh_thumb_opposition",
    "svh_index_distal",
    "svh_index_proximal",
    "svh_middle_distal",
    "svh_middle_proximal",
    "svh_ring",
    "svh_pinky",
    "svh_spread",
)
HAND_PRIMARY_JOINTS = HAND_ACTUATORS
HAND_BASE_BODY = "hand_base"

TOOL_BODY_A = "tool_leg_a"  # the tool frame: origin on the hinge axis, +x toward the tips
TOOL_BODY_B = "tool_leg_b"
TOOL_HINGE = "tool_hinge"
TOOL_FREE_JOINT = "tool_free"
TOOL_TIP_SITES = ("tool_tip_a", "tool_tip_b")
TOOL_HINGE_ACTUATOR = "tool_hinge_cmd"  # privileged direct hinge command

OBJECT_BODY = "object"
OBJECT_FREE_JOINT = "object_free"
OBJECT_GEOM = "object_geom"
TABLE_GEOMS = ("table", "platform")

GRASP_KEYFRAME = "grasp"
SCENES = ("tool_shape", "tool_pick")
