"""Viewers: episode files and datasets in Rerun (``hingelab view``).

One concern per module (data flows down the list):

- ``entities``: the entity paths and timelines of a recording (the contract with the
  blueprints and tests).
- ``episode_series``: an ``Episode`` -> per-step series (numpy, no Rerun).
- ``rerun_send``: a series -> one bulk ``send_columns`` call, plus static styling.
- ``scene_geometry``: the pick scene's meshes per body and their poses per step in hand_base (no Rerun).
- ``robot_log``: those meshes into an episode's 3-D view, posed every step.
- ``latent_frame``: the latent plane's reachable region (the encoder's calibration) and framing.
- ``episode_log``: one episode on its simulated timeline (``step``, ``sim_time``).
- ``dataset_log``: a dataset's overview and all its episodes (``episode``, ``dataset_step``).
- ``blueprints``: the layouts, saved as ``viewers/*.rbl``.
- ``view``: a path -> a recording saved to ``.rrd``, served to the web viewer, or spawned.
"""

from hingelab.viewers.view import ViewError, ViewResult, view

__all__ = ["view", "ViewResult", "ViewError"]
