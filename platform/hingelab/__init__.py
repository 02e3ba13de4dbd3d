"""hingelab: hierarchical RL of articulated-tool use with a multifingered hand.

One import package; its source root is the repository's ``platform/`` folder.
"""

import os
import sys

__version__ = "0.1.0"


def _default_gl_backend() -> None:
    # MuJoCo fixes its OpenGL backend from MUJOCO_GL when it is first imported (glfw if unset, which
    # needs a display): on a headless machine the depth camera renders through EGL, so the default
    # is set here, before any hingelab module imports mujoco (hingelab.sim.depth_render documents it).
    # Linux only: macOS and Windows have no DISPLAY either, and there mujoco's import refuses egl
    if sys.platform.startswith("linux") and "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
        os.environ["MUJOCO_GL"] = "egl"


_default_gl_backend()


from hingelab.tasks import register_envs_with_gymnasium  # noqa: E402  (after the GL backend: before mujoco)

register_envs_with_gymnasium()  # now if Gymnasium is imported, else when it is: `hingelab --help` never loads it
