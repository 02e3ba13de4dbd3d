"""``SimRenderMixin``: ``render()`` (rgb_array) and ``close()`` for the envs over ``SimCore``."""

from __future__ import annotations

import mujoco
import numpy as np


class SimRenderMixin:
    """Needs ``self.sim``, ``self.render_mode`` and ``_camera() -> (lookat (3,), distance, azimuth, elevation)``."""

    _renderer = None

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.sim.model, 240, 320)
        lookat, distance, azimuth, elevation = self._camera()
        camera = mujoco.MjvCamera()
        camera.lookat[:] = np.asarray(lookat)
        camera.distance, camera.azimuth, camera.elevation = distance, azimuth, elevation
        self._renderer.update_scene(self.sim.data, camera)
        return self._renderer.render()

    def close(self):
        perception = getattr(self, "perception", None)
        if perception is not None:
            perception.close()
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
