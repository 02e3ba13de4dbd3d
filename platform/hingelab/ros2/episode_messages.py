"""hingelab's own records as ROS 2 messages with named fields, for the topics no standard type holds.

``labelled_type(ts, topic, fields)`` makes (and registers in the typestore ``ts``) a message type
``hingelab_msgs/msg/<Name>`` for an episode topic: ``std_msgs/Header header`` then one field per
recorded column, named as the column (``info.is_success`` -> ``info_is_success``), typed as it
(float64, float32, int64, bool; a per-step array of shape (n,) a fixed-size array ``float64[n]``,
larger shapes flattened in C order). ``<Name>`` is the episode's own message name (``ToolLatent``,
``RewardTerms``, ``PrivilegedState``, ``Step``, ...), so ``ros2 bag info`` and Foxglove show what each
topic is; the definitions are stored in the bag (``rosbags`` writes them), so readers without a
hingelab_msgs package decode them. A topic's fields follow the episode's task (``Step`` of ToolPick-v0
and of ToolShape-v0 differ), which is why each bag carries its own definitions.

``action_message(ts, values, names)``: the action as ``std_msgs/Float64MultiArray`` (the type the import
reads) with one ``layout.dim`` whose label names the values in order (``action_names``).
``EPISODE_TOPIC``: the episode's metadata as JSON (``std_msgs/String``), which the import reads back.
"""

from __future__ import annotations

import re

import numpy as np
from rosbags.typesys import get_types_from_msg

from hingelab.episodes import schemas as S
from hingelab.json_text import metadata_dumps
from hingelab.sim.names import HAND_ACTUATORS

EPISODE_TOPIC = "/hingelab/episode"
LABELLED_PREFIX = "/hingelab"  # an episode topic /a/b without a standard type goes to /hingelab/a/b
ROS_TYPES = {"float64": "float64", "float32": "float32", "int64": "int64", "int32": "int32", "bool": "bool",
             "uint8": "uint8", "int8": "int8", "uint16": "uint16", "int16": "int16", "uint32": "uint32"}
HIGH_LEVEL_ACTION = ("z_goal_0", "z_goal_1", "hand_velocity_x", "hand_velocity_y", "hand_velocity_z")


def action_names(n: int) -> list[str]:
    """Names of an action's n values: ToolPick-v0's 5 (the latent goal in units of Z_SCALE, the hand velocity in
    units of MAX_SPEED, hingelab.tasks), the low level's 9 (a relative change of each SVH channel), ToolPickFlat-v0's
    12 (both); otherwise action_0 .. action_{n-1}."""
    fingers = [f"delta_{name}" for name in HAND_ACTUATORS]
    known = {5: list(HIGH_LEVEL_ACTION), 9: fingers, 12: fingers + list(HIGH_LEVEL_ACTION[2:])}
    return known.get(n, [f"action_{i}" for i in range(n)])


def action_message(ts, values, names: list[str]):
    T = ts.types
    data = np.asarray(values, float)
    dim = T["std_msgs/msg/MultiArrayDimension"](label=",".join(names), size=len(data), stride=len(data))
    return T["std_msgs/msg/Float64MultiArray"](layout=T["std_msgs/msg/MultiArrayLayout"](dim=[dim], data_offset=0),
                                               data=data)


def episode_message(ts, metadata: dict):
    return ts.types["std_msgs/msg/String"](data=metadata_dumps(metadata))


def field_name(column: str) -> str:
    """A ROS field name for a column: lower case letters, digits and single underscores, starting with a letter."""
    name = re.sub(r"_+", "_", re.sub(r"[^a-z0-9]", "_", column.lower())).strip("_")
    return name if name[:1].isalpha() else f"f_{name}"


def message_name(topic: str) -> str:
    """The episode's own message name for a topic (schemas.TOPIC_TYPES), else the topic in CamelCase."""
    cls = S.TOPIC_TYPES.get(topic)
    if cls is not None:
        return cls.DESCRIPTOR.name
    return "".join(part.capitalize() for part in re.split(r"[^A-Za-z0-9]+", topic) if part) or "Record"


class LabelledType:
    """A registered ``hingelab_msgs/msg/<Name>`` for one episode topic's columns; ``message(ts, header, k)``
    builds row k."""

    def __init__(self, ts, topic: str, fields: dict[str, np.ndarray]):
        self.msgtype = f"hingelab_msgs/msg/{message_name(topic)}"
        self.columns = {}  # column -> (ros field, numpy dtype, per-row size or None for a scalar)
        lines = ["std_msgs/Header header"]
        taken = {"header"}
        for column, values in fields.items():
            values = np.asarray(values)
            if column == "log_time_ns" or values.dtype.name not in ROS_TYPES:
                continue
            name = field_name(column)
            while name in taken:
                name += "_x"
            taken.add(name)
            size = int(np.prod(values.shape[1:])) if values.ndim > 1 else None
            ros = ROS_TYPES[values.dtype.name]
            lines.append(f"{ros}{'' if size is None else f'[{size}]'} {name}")
            self.columns[column] = (name, values.dtype, size)
        ts.register(get_types_from_msg("\n".join(lines) + "\n", self.msgtype))
        self.cls = ts.types[self.msgtype]

    def message(self, header, fields: dict[str, np.ndarray], k: int):
        values = {}
        for column, (name, dtype, size) in self.columns.items():
            row = np.asarray(fields[column][k])
            values[name] = row.item() if size is None else np.ascontiguousarray(row.reshape(-1), dtype=dtype)
        return self.cls(header=header, **values)


__all__ = ["EPISODE_TOPIC", "LABELLED_PREFIX", "LabelledType", "action_message", "action_names", "episode_message",
           "field_name", "message_name"]
