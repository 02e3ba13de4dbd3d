"""An episode's depth camera as a LeRobot depth-image feature, one image per frame.

A trial records its depth camera every ``depth_every``-th control period (``/camera/depth``,
16-bit millimetres; 5 Hz at 20 Hz control), a simulated rollout none. LeRobot has one rate for
every feature, so each frame carries the **latest depth image logged at or before its own log
time** (held over the control periods in between, as a recorder at the frame rate would see
it), and ``info.depth_age_s`` says how old it is (0 at the frames it was taken at). A frame
before an episode's first depth image is one ``DatasetError``: no image is taken from the future.

The image: ``observation.images.depth``, LeRobot 0.6's depth-map convention (``dtype`` "image",
shape (H, W, 1), ``info`` ``{"is_depth_map": true, "depth_unit": "mm"}``): the metric depth as
16-bit unsigned millimetres, lossless (it is what the file holds), 0 where the camera has no
return; LeRobot reads it as float32 (1, H, W) in millimetres and keeps its statistics in
millimetres, not divided by 255. Stored as LeRobot stores depth frames, a TIFF per frame
(``frame-NNNNNN.tiff``, deflate-compressed here) embedded in the data parquet. Not a video: an
8-bit or lossy video would quantize the depth, and no ffmpeg is needed.
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np
from PIL import Image

from hingelab.episodes import codec
from hingelab.episodes import schemas as S
from hingelab.episodes.camera_topics import read_camera
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.reader import EpisodeFile

DEPTH = "observation.images.depth"
DEPTH_AGE = "info.depth_age_s"
DEPTH_UNIT = "mm"
FRAME_FILE = "frame-{frame_index:06d}.tiff"  # LeRobot's DEPTH_FILE_PATTERN: the name an embedded image keeps


def depth_shape(path) -> tuple[int, int] | None:
    """(H, W) of an episode's first depth image, or None if it has none (decodes that one frame)."""
    with EpisodeFile(path) as episode:
        if S.TOPIC_DEPTH not in episode.channels:
            return None
        for _, _, message in episode.iter_messages([S.TOPIC_DEPTH]):
            return tuple(codec.decode_depth_image(message).shape)
    return None


def depth_feature(shape: tuple[int, int]) -> dict:
    return {"dtype": "image", "shape": [int(shape[0]), int(shape[1]), 1], "names": ["height", "width", "channels"],
            "info": {"is_depth_map": True, "depth_unit": DEPTH_UNIT}}


def depth_mm(depth_m: np.ndarray) -> np.ndarray:
    """(H, W) metres -> uint16 millimetres (0: no return), as the file stores them."""
    return np.clip(np.round(np.nan_to_num(depth_m, nan=0.0) * 1000.0), 0, np.iinfo(np.uint16).max).astype(np.uint16)


def encode_mm(mm: np.ndarray) -> bytes:
    """(H, W) uint16 millimetres -> a deflate-compressed 16-bit TIFF."""
    buffer = io.BytesIO()
    Image.fromarray(mm).save(buffer, format="TIFF", compression="tiff_adobe_deflate")
    return buffer.getvalue()


def decode_depth_mm(data: bytes) -> np.ndarray:
    """An embedded depth image back to (H, W) uint16 millimetres."""
    return np.array(Image.open(io.BytesIO(data)), dtype=np.uint16)


@dataclass
class EpisodeDepth:
    """The depth image of each frame: ``images`` (T,) embedded-image dicts, ``age_s`` (T,), ``mm`` (K, H, W) the
    distinct images (for statistics), ``frame_image`` (T,) which of them each frame holds."""

    images: list[dict]
    age_s: np.ndarray
    mm: np.ndarray
    frame_image: np.ndarray


def episode_depth(path, frame_times_ns: np.ndarray, shape: tuple[int, int]) -> EpisodeDepth:
    """Each frame's latest depth image of the episode file ``path`` (module docstring)."""
    record = read_camera(path)
    if record is None or not len(record.log_time_ns):
        raise DatasetError(f"{path}: it has no depth images while other episodes of the export have; export the "
                           "episodes with a camera apart (Dataset(...).filter(source=...))")
    if record.depth.shape[1:] != tuple(shape):
        raise DatasetError(f"{path}: its depth images are {record.depth.shape[1:]}, the export's {tuple(shape)}; "
                           "export one camera resolution at a time")
    frame_times_ns = np.asarray(frame_times_ns, dtype=np.int64)
    latest = np.searchsorted(record.log_time_ns, frame_times_ns, side="right") - 1
    if (latest < 0).any():
        raise DatasetError(f"{path}: frame {int(np.flatnonzero(latest < 0)[0])} comes before the episode's first depth "
                           "image; the export takes no image from the future")
    used = np.unique(latest)
    mm = np.stack([depth_mm(record.depth[i]) for i in used])
    encoded = {int(i): encode_mm(image) for i, image in zip(used, mm)}
    images = [{"bytes": encoded[int(i)], "path": FRAME_FILE.format(frame_index=int(i))} for i in latest]
    age = (frame_times_ns - record.log_time_ns[latest]) / 1e9
    return EpisodeDepth(images=images, age_s=age, mm=mm, frame_image=np.searchsorted(used, latest))


__all__ = ["DEPTH", "DEPTH_AGE", "DEPTH_UNIT", "EpisodeDepth", "decode_depth_mm", "depth_feature", "depth_shape",
           "depth_mm", "encode_mm", "episode_depth"]
