"""Log the robot and the scene into an episode's 3-D view: MJCF meshes, posed every step.

Each body's mesh (``scene_geometry.scene_meshes`` of the pick scene, vertices in the body frame) goes
out once, static, as ``rr.Mesh3D`` at ``world/robot/<body>``; its pose in hand_base goes out on the same
entity as ``rr.Transform3D`` columns on the ``step`` and ``sim_time`` timelines (one ``send_columns``
per body; the object's mesh is the episode's own shape and size where its metadata says, see
``object_spec``). ``world`` is hand_base (``entities``), so the hand stays put and the arm and platform move
around it. Where each part's poses come from is in ``scene_geometry``'s docstring; the episode's facts
panel lists them per episode.
"""

from __future__ import annotations

import functools
import json

import mujoco
import numpy as np
import rerun as rr

from hingelab.episodes import Episode
from hingelab.episodes import schemas as S
from hingelab.errors import ConfigError
from hingelab.viewers import entities as E
from hingelab.viewers.latent_frame import latent_opening
from hingelab.viewers.scene_geometry import BodyMesh, ScenePoses, drawn, scene_meshes, scene_poses


@functools.cache
def _scene() -> tuple[mujoco.MjModel, tuple[BodyMesh, ...]]:
    from hingelab.sim.scene import load_scene

    model = load_scene("tool_pick")
    return model, tuple(scene_meshes(model))


def object_spec(metadata: dict) -> tuple[str, float] | None:
    """(shape, size m) of the episode's object where its metadata says: a primitive shape (``object``, or a
    family's drawn ``object_kind`` with its ``object_draw`` record's ``size_m``); size: the draw's, else the
    training object's (episodes of one fixed object record the shape, not the size). None: not a primitive."""
    from hingelab.sim.objects import SHAPES, TRAINING_OBJECT

    shape, size = metadata.get(S.KEY_OBJECT), TRAINING_OBJECT[1]
    draw = metadata.get(S.KEY_OBJECT_DRAW)
    if draw:
        try:
            record = json.loads(draw)
            shape, size = record.get("kind", shape), float(record.get("size_m", size))
        except (ValueError, TypeError):
            return None
    return (shape, size) if shape in SHAPES else None


@functools.cache
def _object_mesh(shape: str, size: float) -> BodyMesh | None:
    from hingelab.sim.objects import ObjectSpec
    from hingelab.sim.scene import load_scene

    try:
        model = load_scene("tool_pick", obj=ObjectSpec(shape, size))
    except ConfigError:
        return None
    return next((m for m in scene_meshes(model) if m.part == "object"), None)


def _episode_meshes(meshes: tuple[BodyMesh, ...], episode: Episode) -> list[BodyMesh]:
    """The scene's meshes with the object swapped for the episode's own shape and size where it is known."""
    spec = object_spec(episode.metadata)
    swapped = _object_mesh(*spec) if spec is not None else None
    return [swapped if swapped is not None and m.part == "object" else m for m in meshes]


def robot_entity(mesh: BodyMesh) -> str:
    """The entity path of one body's mesh."""
    return f"{E.ROBOT}/{mesh.name}"


def log_robot(rec: rr.RecordingStream, episode: Episode) -> ScenePoses | str:
    """Send the posed meshes of ``episode`` (see the module docstring); the poses, or why none were drawn."""
    model, meshes = _scene()
    try:
        poses = scene_poses(model, episode, [m.body_id for m in meshes], opening_of_z=latent_opening)
    except ConfigError as exc:  # the rest of the episode is still worth seeing
        return str(exc)
    if poses is None:
        return f"the episode has no {S.TOPIC_JOINTS}"
    indexes = [rr.TimeColumn(E.TIMELINE_STEP, sequence=poses.step),
               rr.TimeColumn(E.TIMELINE_SIM_TIME, duration=poses.step_time_ns.astype("timedelta64[ns]"))]
    for b, mesh in enumerate(_episode_meshes(meshes, episode)):
        if not drawn(mesh, poses):
            continue
        entity = robot_entity(mesh)
        rec.log(entity, rr.Mesh3D(vertex_positions=mesh.vertices, triangle_indices=mesh.triangles,
                                  vertex_colors=mesh.colors), static=True)
        rec.send_columns(entity, indexes=indexes, columns=rr.Transform3D.columns(
            translation=poses.translation[:, b], quaternion=poses.quaternion[:, b]))
    return poses


class DatasetRobot:
    """The posed meshes of many episodes back to back (a dataset view): ``add`` each episode, then ``send`` once.

    Poses are kept every ``every`` steps (and at each episode's last step), like the dataset view's
    clouds; a body goes out only for the episodes that can pose it (the arm and platform need arm joints).
    """

    def __init__(self, every: int = 1):
        self.every = max(int(every), 1)
        self.model, self.meshes = _scene()
        self.rows: dict[int, list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]] = {}

    def add(self, episode: Episode, episode_number: int, step_offset: int) -> None:
        try:
            poses = scene_poses(self.model, episode, [m.body_id for m in self.meshes], opening_of_z=latent_opening,
                                every=self.every)
        except ConfigError:  # hand joints of another hand: this episode's scene is left out
            return
        if poses is None or not len(poses.step):
            return
        for b, mesh in enumerate(self.meshes):
            if drawn(mesh, poses):
                self.rows.setdefault(b, []).append((poses.translation[:, b], poses.quaternion[:, b],
                                                    np.full(len(poses.step), episode_number, np.int64),
                                                    poses.step + step_offset))

    def send(self, rec: rr.RecordingStream) -> None:
        for b, parts in self.rows.items():
            mesh = self.meshes[b]
            entity = robot_entity(mesh)
            rec.log(entity, rr.Mesh3D(vertex_positions=mesh.vertices, triangle_indices=mesh.triangles,
                                      vertex_colors=mesh.colors), static=True)
            indexes = [rr.TimeColumn(E.TIMELINE_EPISODE, sequence=np.concatenate([p[2] for p in parts])),
                       rr.TimeColumn(E.TIMELINE_DATASET_STEP, sequence=np.concatenate([p[3] for p in parts]))]
            rec.send_columns(entity, indexes=indexes, columns=rr.Transform3D.columns(
                translation=np.concatenate([p[0] for p in parts]), quaternion=np.concatenate([p[1] for p in parts])))


def sources_markdown(poses: ScenePoses | str) -> str:
    """Where each part's poses came from (or why the scene is not drawn), markdown for the episode's facts panel."""
    if isinstance(poses, str):
        return f"\n## the scene's poses (in hand_base)\n\nnot drawn: {poses}\n"
    lines = ["", "## the scene's poses (in hand_base)", "", "| part | source |", "|---|---|"]
    lines += [f"| {part} | {source} |" for part, source in poses.sources.items()]
    return "\n".join(lines) + "\n"


__all__ = ["log_robot", "robot_entity", "object_spec", "sources_markdown", "DatasetRobot"]
