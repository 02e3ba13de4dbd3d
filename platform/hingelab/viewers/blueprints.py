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

``save_blueprints(folder)`` writes both as ``.rbl`` files (``viewers/`` keeps them; refresh
them with ``python -c "from hingelab.viewers.blueprints import save_blueprints;
save_blueprints('viewers')"``): open one in the Rerun viewer (File > Open) next to any
hingelab recording. Every ``.rrd`` that ``hingelab view`` saves carries its blueprint too.
"""

from __future__ import annotations

from pathlib import Path

import rerun.blueprint as rrb

from hingelab.viewers import entities as E

EPISODE_BLUEPRINT_FILE = "episode_blueprint.rbl"
DATASET_BLUEPRINT_FILE = "dataset_blueprint.rbl"
# The latent plane shows z in [-3, 3]^2: the VAE's prior is N(0, I), so nearly all latents fall inside.
LATENT_BOUNDS = rrb.VisualBounds2D(x_range=[-3.0, 3.0], y_range=[-3.0, 3.0])


def _latent_bounds(bounds) -> rrb.VisualBounds2D:
    """``bounds`` (x_range, y_range) from ``latent_frame.plane_bounds``, or the prior's [-3, 3]^2."""
    if bounds is None:
        return LATENT_BOUNDS
    return rrb.VisualBounds2D(x_range=list(bounds[0]), y_range=list(bounds[1]))


def _episode_views(latent_bounds=None) -> rrb.Container:
    scene = rrb.Spatial3DView(
        name="scene in hand_base", origin=E.WORLD,
        contents=["$origin/**"],
    )
    plane = rrb.Spatial2DView(
        name="latent plane (z, z_goal, reachable)", origin="latent_plane",
        contents=["$origin/**"], visual_bounds=_latent_bounds(latent_bounds),
    )
    series = rrb.Tabs(
        rrb.TimeSeriesView(name="latent z, z_smoothed, z_goal", origin="latent"),
        rrb.TimeSeriesView(name="hand joints (rad)", origin="hand"),
        active_tab=0,
    )
    reward = rrb.TimeSeriesView(name="reward terms", origin=E.REWARD)
    outcome = rrb.TimeSeriesView(name="hinge angle (rad), success, attempt",
                                 contents=[E.HINGE_ANGLE, E.SUCCESS, E.ATTEMPT])
    side = rrb.Vertical(
        rrb.TextDocumentView(name="episode", origin=E.FACTS),
        rrb.TextLogView(name="events", origin=E.EVENTS),
        # robot trials: the depth camera's image (empty for simulated rollouts, which record no camera)
        rrb.Spatial2DView(name="depth camera", origin=E.CAMERA),
        row_shares=[3, 1, 2],
    )
    return rrb.Vertical(
        rrb.Horizontal(scene, plane, side, column_shares=[3, 2, 1.2]),
        rrb.Horizontal(series, reward, outcome),
        row_shares=[3, 2],
        name="episode",
    )


def episode_blueprint(latent_bounds=None) -> rrb.Blueprint:
    """Layout of a one-episode recording (see the module docstring); ``latent_bounds``: (x_range, y_range)
    of the latent plane (``latent_frame.plane_bounds``), default the prior's [-3, 3]^2."""
    return rrb.Blueprint(_episode_views(latent_bounds), rrb.TimePanel(state="collapsed"),
                         rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"))


def _overview_views(latent_bounds=None) -> rrb.Container:
    bars = rrb.Vertical(
        rrb.BarChartView(name="success rate by object", origin=E.SUCCESS_BY_OBJECT),
        rrb.BarChartView(name="success rate by source", origin=E.SUCCESS_BY_SOURCE),
    )
    per_episode = rrb.Vertical(
        rrb.TimeSeriesView(name="return per episode", origin=E.EPISODE_RETURN),
        rrb.TimeSeriesView(name="length per episode (steps)", origin=E.EPISODE_LENGTH),
        rrb.TimeSeriesView(name="success per episode", origin=E.EPISODE_SUCCESS),
    )
    plane = rrb.Spatial2DView(name="all latents (green: success, red: failure)", origin=E.ALL_LATENTS,
                              visual_bounds=_latent_bounds(latent_bounds))
    return rrb.Horizontal(
        bars, per_episode, rrb.Vertical(plane, rrb.TextDocumentView(name="summary", origin=E.SUMMARY)),
        name="overview",
    )


def dataset_blueprint(latent_bounds=None) -> rrb.Blueprint:
    """Layout of a dataset recording (see the module docstring); ``latent_bounds`` as ``episode_blueprint``'s."""
    return rrb.Blueprint(rrb.Tabs(_overview_views(latent_bounds), _episode_views(latent_bounds), active_tab=0),
                         rrb.TimePanel(state="collapsed"), rrb.BlueprintPanel(state="collapsed"),
                         rrb.SelectionPanel(state="collapsed"))


def save_blueprints(folder) -> list[Path]:
    """Write ``episode_blueprint.rbl`` and ``dataset_blueprint.rbl`` into ``folder``, the latent plane framed
    to the shipped encoder's reachable region."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    from hingelab.viewers.latent_frame import plane_bounds, reachable_latent_curve  # torch: the encoder

    bounds = plane_bounds(reachable_latent_curve())  # the shipped encoder's reachable region
    for name, blueprint in ((EPISODE_BLUEPRINT_FILE, episode_blueprint(bounds)),
                            (DATASET_BLUEPRINT_FILE, dataset_blueprint(bounds))):
        blueprint.save(E.APPLICATION_ID, folder / name)
        written.append(folder / name)
    return written


__all__ = ["episode_blueprint", "dataset_blueprint", "save_blueprints",
           "EPISODE_BLUEPRINT_FILE", "DATASET_BLUEPRINT_FILE"]
