"""Log an episode's depth camera to Rerun: the depth image, the camera's frustum and pose beside the cloud.

For episodes with camera topics (schema 3: ``hingelab trial``): ``world/camera`` carries the
camera's pose in hand_base (a transform per recorded frame) and its pinhole (the intrinsics, drawn
as a frustum in the 3-D view), ``world/camera/depth`` the depth image (millimetres, shown in the
camera's own 2-D view and projected into the 3-D one). Frames go out on the episode's ``step``
and ``sim_time`` timelines at the steps they were recorded.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from hingelab.episodes import Episode
from hingelab.episodes import schemas as S
from hingelab.episodes.camera_topics import read_camera
from hingelab.viewers import entities as E


def log_camera(rec: rr.RecordingStream, episode: Episode) -> bool:
    """Send the camera of ``episode`` (if it has one); True if it did."""
    if S.TOPIC_DEPTH not in episode.topics:
        return False
    camera = read_camera(episode.path)
    if camera is None or len(camera.depth) == 0:
        return False
    k = camera.intrinsics
    rec.log(E.CAMERA, rr.Pinhole(image_from_camera=[[k.fx, 0, k.cx], [0, k.fy, k.cy], [0, 0, 1]],
                                 resolution=[k.width, k.height], camera_xyz=rr.ViewCoordinates.RDF,
                                 image_plane_distance=0.1), static=True)
    # the step each frame belongs to: frames are recorded at step times
    step_times = episode.topics.get(S.TOPIC_STEP, episode.topics.get(S.TOPIC_JOINTS, {})).get("log_time_ns")
    steps = (np.searchsorted(step_times, camera.log_time_ns) if step_times is not None
             else np.arange(len(camera.log_time_ns)))
    start = int(step_times[0]) if step_times is not None and len(step_times) else int(camera.log_time_ns[0])
    indexes = [rr.TimeColumn(E.TIMELINE_STEP, sequence=steps),
               rr.TimeColumn(E.TIMELINE_SIM_TIME,
                             duration=(camera.log_time_ns - start).astype("timedelta64[ns]"))]
    rec.send_columns(E.CAMERA, indexes=indexes, columns=rr.Transform3D.columns(
        translation=camera.position, mat3x3=camera.rotation))
    for i, depth in enumerate(camera.depth):  # one image a call: a frame is 0.7 MB
        rec.set_time(E.TIMELINE_STEP, sequence=int(steps[i]))
        rec.set_time(E.TIMELINE_SIM_TIME, duration=np.timedelta64(int(camera.log_time_ns[i] - start), "ns"))
        rec.log(E.CAMERA_DEPTH, rr.DepthImage(np.rint(depth * 1000).astype(np.uint16), meter=1000.0,
                                              colormap="viridis"))
    return True


__all__ = ["log_camera"]
