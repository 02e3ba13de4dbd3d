"""The Rerun blueprints (view layouts) of ``hingelab view``, built in code and kept as files.

``episode_blueprint()``: the 3-D view in hand_base (the scene's meshes, cloud, tool frame,
tips, object, target; a trial's camera frustum) beside the latent plane (z and z_goal, the
trajectory) and the depth camera's image (trials), and below
them time series of the latent, the hand joints, the reward terms and the hinge
angle with the success and attempt markers, plus the episode's facts and events.

``dataset_blueprint()``: a tab ``overview`` (success-rate bar charts per object and
source, return/length/success per episode, all latents over the latent plane, the
summary tables) and a tab ``episodes`` with the episode layout on the dataset's
timelines (scrub ``episode`` to step through episodes).

Each takes a ``kind`` of dataset (``KINDS``: heuristic, low level, high level, trial, real;
``dataset_kind(source)`` maps a dataset's or episode's source to it): the episode layout's views
are rearranged for it (the latent plane leads for the low level, the depth camera for trials, the
attempts for the high level; views without data for the kind are left out).

``save_blueprints(folder)`` writes them as ``.rbl`` files (``viewers/`` keeps them; refresh
them with ``python -c "from hingelab.viewers.blueprints import save_blueprints;
save_blueprints('viewers')"``): open one in the Rerun viewer (File > Open) next to any
hingelab recording. Every ``.rrd`` that ``hingelab view`` saves carries its blueprint too.
"""

from __future__ import annotations

from pathlib import Path

import rerun as rr
import rerun.blueprint as rrb

from hingelab.viewers import entities as E

EPISODE_BLUEPRINT_FILE = "episode_blueprint.rbl"
DATASET_BLUEPRINT_FILE = "dataset_blueprint.rbl"
GENERIC = "generic"
KINDS = ("heuristic", "low_level", "high_level", "trial", "real")  # of datasets, from their source (dataset_kind)


def kind_blueprint_file(kind: str) -> str:
    """The .rbl file of a kind's dataset layout."""
    return f"dataset_blueprint_{kind}.rbl"


# The 3-D view's first eye, in hand_base (+x up): half a metre away, diagonally between the side the tweezer
# opens to (+y) and the fingers' direction (+z), looking between the held tweezer and the object under its
# tips, so the tool, its cloud and the object fill the view rather than the whole arm (orbit or zoom out).
SCENE_LOOK_TARGET_HAND = (-0.06, 0.03, 0.12)
SCENE_EYE = rrb.EyeControls3D(kind="Orbital", position=(-0.01, 0.35, 0.44), look_target=SCENE_LOOK_TARGET_HAND,
                              eye_up=(1.0, 0.0, 0.0))
# The latent plane shows z in [-3, 3]^2: the VAE's prior is N(0, I), so nearly all latents fall inside.
LATENT_BOUNDS = rrb.VisualBounds2D(x_range=[-3.0, 3.0], y_range=[-3.0, 3.0])
SUCCESS_RANGE = (-0.1, 1.1)  # the 0/1 success points inside the plot, not on its edges


def _latent_bounds(bounds) -> rrb.VisualBounds2D:
    """``bounds`` (x_range, y_range) from ``latent_frame.plane_bounds``, or the prior's [-3, 3]^2."""
    if bounds is None:
        return LATENT_BOUNDS
    return rrb.VisualBounds2D(x_range=list(bounds[0]), y_range=list(bounds[1]))


def dataset_kind(source: str | None) -> str:
    """The kind of dataset a ``source`` (card or episode metadata) belongs to: one of ``KINDS``, else generic."""
    source = (source or "").lower()
    if source in ("heuristic", "scripted", "scripted-feedback"):
        return "heuristic"
    if source.startswith("low_level"):
        return "low_level"
    if source.startswith(("high_level", "flat")):
        return "high_level"
    if source == "stand_in":
        return "trial"
    if source == "real":
        return "real"
    return GENERIC


def _episode_views(latent_bounds=None, kind: str = "generic") -> rrb.Container:
    """The episode layout for a ``kind`` of dataset (``KINDS``): which views lead and which are left out."""
    scene = rrb.Spatial3DView(name="scene in hand_base", origin=E.WORLD, contents=["$origin/**"],
                              eye_controls=SCENE_EYE)
    plane = rrb.Spatial2DView(
        name="latent plane (z, z_goal, reachable)", origin="latent_plane",
        contents=["$origin/**"], visual_bounds=_latent_bounds(latent_bounds),
    )
    latent = rrb.TimeSeriesView(name="latent z, z_smoothed, z_goal", origin="latent")
    joints = rrb.TimeSeriesView(name="hand joints (rad)", origin="hand")
    reward = rrb.TimeSeriesView(name="reward terms", origin=E.REWARD)
    outcome = rrb.TimeSeriesView(name="hinge angle (rad), success, attempt",
                                 contents=[E.HINGE_ANGLE, E.SUCCESS, E.ATTEMPT])
    attempts = rrb.TimeSeriesView(name="success, attempt", contents=[E.SUCCESS, E.ATTEMPT])
    facts = rrb.TextDocumentView(name="episode", origin=E.FACTS)
    events = rrb.TextLogView(name="events", origin=E.EVENTS)
    # robot trials: the depth camera's image (empty for simulated rollouts, which record no camera)
    depth = rrb.Spatial2DView(name="depth camera", origin=E.CAMERA)
    title = "episode" if kind == GENERIC else f"episode ({kind.replace('_', ' ')})"
    if kind == "heuristic":  # the privileged demonstrator: the scene and the hand's motion
        top = rrb.Horizontal(scene, plane, rrb.Vertical(facts, events, row_shares=[3, 1]), column_shares=[3, 1.5, 1.2])
        bottom = rrb.Horizontal(rrb.Tabs(joints, latent), outcome, reward)
    elif kind == "low_level":  # shaping the tweezer toward latent goals: the plane leads
        top = rrb.Horizontal(plane, scene, rrb.Vertical(facts, events, row_shares=[3, 1]), column_shares=[2.5, 2, 1.2])
        bottom = rrb.Horizontal(latent, reward, rrb.Tabs(outcome, joints))
    elif kind == "high_level":  # picking: the scene, the attempts, the rewards
        top = rrb.Horizontal(scene, plane, rrb.Vertical(facts, events, row_shares=[3, 1]), column_shares=[3, 1.5, 1.2])
        bottom = rrb.Horizontal(attempts, reward, rrb.Tabs(latent, joints))
    elif kind == "trial":  # the stand-in rig: what the camera saw beside the scene; no privileged state
        top = rrb.Horizontal(scene, depth, rrb.Vertical(facts, events, row_shares=[3, 1]), column_shares=[2.5, 2, 1.2])
        bottom = rrb.Horizontal(rrb.Tabs(latent, joints), plane, attempts)
    elif kind == "real":  # a rig's recording: joints and the perceived tool, no simulator truth
        top = rrb.Horizontal(scene, plane, rrb.Vertical(facts, events, depth, row_shares=[3, 1, 2]),
                             column_shares=[3, 1.5, 1.2])
        bottom = rrb.Horizontal(latent, joints, attempts)
    else:
        top = rrb.Horizontal(scene, plane, rrb.Vertical(facts, events, depth, row_shares=[3, 1, 2]),
                             column_shares=[3, 2, 1.2])
        bottom = rrb.Horizontal(rrb.Tabs(latent, joints, active_tab=0), reward, outcome)
    return rrb.Vertical(top, bottom, row_shares=[3, 2], name=title)


def episode_blueprint(latent_bounds=None, kind: str = GENERIC) -> rrb.Blueprint:
    """Layout of a one-episode recording (see the module docstring); ``latent_bounds``: (x_range, y_range)
    of the latent plane (``latent_frame.plane_bounds``), default the prior's [-3, 3]^2; ``kind``: ``KINDS``."""
    return rrb.Blueprint(_episode_views(latent_bounds, kind),
                         rrb.TimePanel(state="collapsed", timeline=E.TIMELINE_STEP, play_state="paused"),
                         rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"))


def _per_episode_axis(extent) -> rrb.archetypes.TimeAxis | None:
    """The per-episode plots' x axis: all ``extent`` = (episodes, steps) of the recording on ``dataset_step``
    with a margin on each side (Rerun's default is a window of about 1,000 around the time cursor, and a
    visible time range does not move it; the range is in steps, so on timeline ``episode`` zoom out)."""
    if extent is None:
        return None
    last = max(extent[1] - 1, 0)
    pad = max(1, round(0.02 * last))
    return rrb.archetypes.TimeAxis(view_range=rr.TimeRange(start=rrb.TimeRangeBoundary.absolute(seq=-pad),
                                                           end=rrb.TimeRangeBoundary.absolute(seq=last + pad)))


def _overview_views(latent_bounds=None, extent=None) -> rrb.Container:
    bars = rrb.Vertical(
        rrb.BarChartView(name="success rate by object", origin=E.SUCCESS_BY_OBJECT),
        rrb.BarChartView(name="success rate by source", origin=E.SUCCESS_BY_SOURCE),
    )
    # one point per episode at its middle dataset_step (the layout's timeline; scrub `episode` for numbers)
    axis_x = _per_episode_axis(extent)
    per_episode = rrb.Vertical(
        rrb.TimeSeriesView(name="return per episode", origin=E.EPISODE_RETURN, axis_x=axis_x),
        rrb.TimeSeriesView(name="length per episode (steps)", origin=E.EPISODE_LENGTH, axis_x=axis_x),
        rrb.TimeSeriesView(name="success per episode (1: success)", origin=E.EPISODE_SUCCESS, axis_x=axis_x,
                           axis_y=rrb.archetypes.ScalarAxis(range=SUCCESS_RANGE)),
    )
    plane = rrb.Spatial2DView(name="all latents (green: success, red: failure)", origin=E.ALL_LATENTS,
                              visual_bounds=_latent_bounds(latent_bounds))
    return rrb.Horizontal(
        bars, per_episode, rrb.Vertical(plane, rrb.TextDocumentView(name="summary", origin=E.SUMMARY)),
        name="overview",
    )


def dataset_blueprint(latent_bounds=None, kind: str = GENERIC, extent: tuple[int, int] | None = None) -> rrb.Blueprint:
    """Layout of a dataset recording (see the module docstring); ``latent_bounds``, ``kind`` as
    ``episode_blueprint``'s; ``extent``: (episodes, steps) the recording holds, so that the per-episode plots
    show them all (default: Rerun's window around the time cursor)."""
    # dataset_step: the episodes' series back to back, and the overview's per-episode points among them
    tabs = rrb.Tabs(_overview_views(latent_bounds, extent), _episode_views(latent_bounds, kind), active_tab=0)
    return rrb.Blueprint(tabs,
                         rrb.TimePanel(state="collapsed", timeline=E.TIMELINE_DATASET_STEP, play_state="paused"),
                         rrb.BlueprintPanel(state="collapsed"),
                         rrb.SelectionPanel(state="collapsed"))


def save_blueprints(folder) -> list[Path]:
    """Write ``episode_blueprint.rbl``, ``dataset_blueprint.rbl`` and one ``dataset_blueprint_<kind>.rbl`` per
    ``KINDS`` into ``folder``, the latent plane framed to the shipped encoder's reachable region."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    from hingelab.viewers.latent_frame import plane_bounds, reachable_latent_curve  # torch: the encoder

    bounds = plane_bounds(reachable_latent_curve())  # the shipped encoder's reachable region
    layouts = [(EPISODE_BLUEPRINT_FILE, episode_blueprint(bounds)), (DATASET_BLUEPRINT_FILE, dataset_blueprint(bounds))]
    layouts += [(kind_blueprint_file(kind), dataset_blueprint(bounds, kind)) for kind in KINDS]
    for name, blueprint in layouts:
        blueprint.save(E.APPLICATION_ID, folder / name)
        written.append(folder / name)
    return written


__all__ = ["episode_blueprint", "dataset_blueprint", "save_blueprints", "dataset_kind", "kind_blueprint_file", "KINDS",
           "EPISODE_BLUEPRINT_FILE", "DATASET_BLUEPRINT_FILE"]
