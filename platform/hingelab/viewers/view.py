"""``view(path, ...)``: an episode file or a dataset folder -> a Rerun recording.

Where the recording goes:

- ``save=FILE.rrd``: written to that file (with the blueprint inside, so ``rerun FILE.rrd``
  opens the layout); also the default on a machine without a display, as ``./<name>.rrd``;
- ``web=True``: saved to a private temporary .rrd and served to Rerun's web viewer by the
  bundled ``rerun`` executable, on 127.0.0.1 unless ``bind`` says otherwise (``web_server``;
  the CLI keeps serving until Ctrl-C);
- otherwise (a display is present): a native viewer is spawned.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import rerun as rr

from hingelab.episodes import read_episode
from hingelab.episodes import schemas as S
from hingelab.episodes.card import CARD_FILE
from hingelab.episodes.dataset import Dataset, open_dataset
from hingelab.errors import HingelabError
from hingelab.safe_names import safe_file_name
from hingelab.viewers import entities as E
from hingelab.viewers.blueprints import dataset_blueprint, dataset_kind, episode_blueprint
from hingelab.viewers.dataset_log import DatasetLogStats, log_dataset
from hingelab.viewers.episode_log import log_episode
from hingelab.viewers.latent_frame import plane_bounds, reachable_latent_curve
from hingelab.viewers.web_server import GRPC_PORT, LOOPBACK, WEB_PORT, WebServer, serve_rrd, serving_workdir


class ViewError(HingelabError):
    """A path that cannot be viewed (missing, not an episode or dataset, empty)."""


@dataclass
class ViewResult:
    """What ``view`` produced: the kind of path, where it went, counts and wall time (s)."""

    kind: str  # "episode" or "dataset"
    name: str
    saved_to: Path | None
    url: str | None
    episodes: int
    steps: int
    seconds: float
    stats: DatasetLogStats | None = field(default=None)
    server: WebServer | None = field(default=None)  # web: the running server (``stop()`` ends it)


def has_display() -> bool:
    """True where a native viewer window can open (an X11/Wayland display, or macOS/Windows)."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _target(path: Path) -> tuple[str, Dataset | Path]:
    if not path.exists():
        raise ViewError(f"{path} does not exist; give an episode file (.mcap) or a dataset folder")
    if path.is_file():
        if path.suffix != ".mcap":
            raise ViewError(f"{path} is not an episode file (.mcap) or a dataset folder")
        return "episode", path
    dataset = open_dataset(path)
    if len(dataset) == 0:
        raise ViewError(f"{path} has no episodes in {dataset.episodes_dir}; generate some first")
    if dataset.index["success"].isna().all():
        raise ViewError(f"no episode of {path} records 'success' in its metadata; the dataset view counts "
                        "outcomes: rewrite the episodes with EpisodeWriter.set_outcome")
    return "dataset", dataset


def _file_name(name: str, kind: str, target) -> str:
    """The recording's default file name: a dataset's name is a fact of its card, checked before it names a file."""
    if kind == "episode":
        return name
    return safe_file_name(name, "the dataset card's name", target.root / CARD_FILE, fix="give --save FILE.rrd")


def _open_recording(name: str, blueprint, save: Path | None) -> rr.RecordingStream:
    rec = rr.RecordingStream(E.APPLICATION_ID, recording_id=E.RECORDING_ID_PREFIX + name)
    if save is not None:
        save.parent.mkdir(parents=True, exist_ok=True)
        rec.save(save, default_blueprint=blueprint)
    else:
        rec.spawn(default_blueprint=blueprint)
    return rec


def _episode_plane_bounds(episode):
    """The latent plane's frame: the reachable region and the episode's z and z_goal (no latent: the default)."""
    latent = episode.topics.get(S.TOPIC_LATENT, {})
    if "z" not in latent:
        return None
    goal = episode.topics.get(S.TOPIC_GOAL, {}).get("z_goal")
    return plane_bounds(reachable_latent_curve(), latent["z"], goal)


def view(path, save=None, web: bool = False, cloud_every: int = 10, max_episodes: int | None = None,
         progress: bool = True, bind: str = LOOPBACK, port: int = GRPC_PORT,
         web_port: int = WEB_PORT) -> tuple[ViewResult, rr.RecordingStream]:
    """Log ``path`` (episode file or dataset folder) to Rerun; see the module docstring.

    Returns the result and the (finished) recording stream. With ``web`` the result's
    ``server`` is serving it on ``bind``:``port`` (gRPC) and ``bind``:``web_port`` (the web
    viewer, ``result.url``) until the caller calls ``result.server.stop()``.
    """
    started = time.perf_counter()
    path = Path(path)
    kind, target = _target(path)
    name = path.stem if kind == "episode" else target.card.name
    # a default file name is checked before anything is made (a dataset's name comes from its card)
    file_name = _file_name(name, kind, target) if save is None and (web or not has_display()) else None
    if save is None and not web and not has_display():
        save = Path.cwd() / f"{file_name}.rrd"
    save = Path(save) if save is not None else None
    if save is not None and save.suffix != ".rrd":
        raise ViewError(f"--save {save}: a Rerun recording file must end in .rrd")
    if web and save is not None:
        raise ViewError("give either save (an .rrd file) or web, not both")
    workdir = serving_workdir() if web else None
    if workdir is not None:
        save = Path(workdir.name) / f"{file_name}.rrd"
    if kind == "episode":
        episode = read_episode(target)  # before opening the sink: a bad file leaves no .rrd behind
        kind_of = dataset_kind(episode.metadata.get(S.KEY_SOURCE))
        rec = _open_recording(name, episode_blueprint(_episode_plane_bounds(episode), kind_of), save)
        log_episode(rec, episode)
        result = ViewResult(kind, name, save, None, 1, episode.length, 0.0)
    else:
        held = target.index.iloc[: len(target.paths()[:max_episodes])]  # the episodes the recording will hold
        blueprint = dataset_blueprint(plane_bounds(reachable_latent_curve()), dataset_kind(target.card.source),
                                      extent=(len(held), int(held["length"].fillna(0).sum())))
        rec = _open_recording(name, blueprint, save)
        stats = log_dataset(rec, target, cloud_every=cloud_every, max_episodes=max_episodes, progress=progress)
        result = ViewResult(kind, name, save, None, stats.episodes, stats.steps, 0.0, stats)
    rec.flush()
    rec.disconnect()  # writes the .rrd footer
    if workdir is not None:
        result.saved_to = None  # a private temporary file, removed when the server stops
        result.server = serve_rrd(save, address=bind, grpc_port=port, web_port=web_port, workdir=workdir)
        result.url = result.server.url
    result.seconds = time.perf_counter() - started
    return result, rec


__all__ = ["view", "ViewResult", "ViewError", "has_display"]
