"""Reading an episode's camera topics back (schema 3): depth frames, the calibration, the camera's pose.

They are not in ``/episode/columns`` (a depth frame is 0.7 MB), so ``read_episode`` gives only their
log times; ``read_camera`` decodes the messages themselves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from hingelab.camera import DepthIntrinsics
from hingelab.episodes import codec
from hingelab.episodes import schemas as S
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.reader import EpisodeFile, corrupt_error


@dataclass
class CameraRecord:
    """An episode's camera: ``depth`` (T, H, W) float32 m, their log times (T,) ns, the intrinsics, and the
    camera's pose in hand_base per frame: ``rotation`` (T, 3, 3), ``position`` (T, 3)."""

    log_time_ns: np.ndarray
    depth: np.ndarray
    intrinsics: DepthIntrinsics | None
    rotation: np.ndarray
    position: np.ndarray


def read_camera(path) -> CameraRecord | None:
    """The camera topics of an episode file, or None if it has none (schema 1-2 files, simulated rollouts)."""
    try:
        with EpisodeFile(path) as episode:
            if S.TOPIC_DEPTH not in episode.channels:
                return None
            times, frames, rotations, positions, intrinsics = [], [], [], [], None
            for topic, t, message in episode.iter_messages(list(S.CAMERA_TOPICS)):
                if topic == S.TOPIC_DEPTH:
                    times.append(t)
                    frames.append(codec.decode_depth_image(message))
                elif topic == S.TOPIC_CAMERA_POSE:
                    r = message.rotation
                    rotations.append(Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix())
                    positions.append([message.translation.x, message.translation.y, message.translation.z])
                elif intrinsics is None:
                    k = message.K
                    intrinsics = DepthIntrinsics("recorded", message.width, message.height, k[0], k[4], k[2], k[5],
                                                 0.0, 65.535)
    except DatasetError:
        raise
    except Exception as exc:  # noqa: BLE001 - whatever a corrupt file makes a decoder raise
        raise corrupt_error(path, exc) from exc
    return CameraRecord(np.asarray(times, np.int64), np.stack(frames), intrinsics, np.asarray(rotations),
                        np.asarray(positions))
