"""hingelab: hierarchical RL of articulated-tool use with a multifingered hand.

One import package; its source root is the repository's ``platform/`` folder.
"""

__version__ = "0.1.0"


def _register() -> None:
    from hingelab.envs import register_envs

    register_envs()


_register()
