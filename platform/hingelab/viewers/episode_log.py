"""Log one episode to a Rerun recording on its simulated timeline.

Every per-step series goes out as columns on the timelines ``step`` (control step)
and ``sim_time`` (seconds), so scrubbing either replays the episode. Static parts:
hand_base as the 3-D frame, the scene's meshes from the MJCF posed every step
(``robot_log``), the tool frame's axes, series names and colors, the
episode's facts, the latent trajectory on the latent plane and the tips' path. Episodes with
a camera (robot trials) add its depth image and frustum (``camera_log``).
"""

from __future__ import annotations

import rerun as rr

from hingelab.episodes import Episode
from hingelab.viewers import entities as E
from hingelab.viewers.camera_log import log_camera
from hingelab.viewers.episode_series import (
    Series,
    episode_facts_markdown,
    episode_series,
    latent_trajectory,
    tip_midpoints,
)
from hingelab.viewers.latent_frame import reachable_latent_curve
from hingelab.viewers.rerun_send import (
    COLORS,
    LINE_RADIUS_UI,
    episode_indexes,
    send_scene_statics,
    send_series,
    send_static_style,
)
from hingelab.viewers.robot_log import log_robot, sources_markdown


def log_episode(rec: rr.RecordingStream, episode: Episode) -> list[Series]:
    """Send ``episode`` to ``rec`` (see the module docstring); returns the series sent."""
    send_scene_statics(rec)
    series = episode_series(episode)
    for one in series:
        send_static_style(rec, one)
        send_series(rec, one, episode_indexes(one))
    poses = log_robot(rec, episode)  # the arm, hand, tweezer, platform and object as posed meshes
    facts = episode_facts_markdown(episode) + sources_markdown(poses)
    rec.log(E.FACTS, rr.TextDocument(facts, media_type="text/markdown"), static=True)
    trajectory = latent_trajectory(episode)
    if trajectory is not None and len(trajectory) > 1:
        rec.log(E.PLANE_TRAJECTORY, rr.LineStrips2D([trajectory], colors=[(150, 150, 150)], radii=[LINE_RADIUS_UI]),
                static=True)
    reachable = reachable_latent_curve() if trajectory is not None else None
    if reachable is not None:
        rec.log(E.PLANE_REACHABLE, rr.LineStrips2D([reachable], colors=[(200, 200, 200)], radii=[-3.0],
                                                   labels=["reachable"], show_labels=False), static=True)
    path = tip_midpoints(episode)
    if path is not None and len(path) > 1:
        rec.log(E.TIP_PATH, rr.LineStrips3D([path], colors=[COLORS[E.TIPS]], radii=[0.0005]), static=True)
    log_camera(rec, episode)  # trials: the depth image and the camera's frustum beside the cloud
    return series


__all__ = ["log_episode"]
