"""Flags several commands share."""

from __future__ import annotations

import argparse
import os

from hingelab.bounded_reads import DEFAULT_MAX_MESH_MB, MAX_MESH_MB_ENV
from hingelab.cli.names import OBJECT_NOISE_GAUSSIAN, OBJECT_NOISE_MODEL, OBJECT_PERCEPTIONS
from hingelab.paths import REPO_ROOT


def add_on_corrupt(p) -> None:
    """``--on-corrupt stop|skip``: what a command does with episode files it cannot read (``main`` applies it
    to every dataset the command opens, through ``hingelab.episodes.dataset.corrupt_policy``)."""
    p.add_argument("--on-corrupt", choices=("stop", "skip"), default="stop",
                   help="episode files that cannot be read (corrupt, cut off): stop (the default) names them all "
                        "and ends; skip leaves them out and says how many")


def add_ray_argument(p) -> None:
    """``--ray [ADDR]``: episodes as Ray tasks, on a local one-node Ray or the cluster at ADDR."""
    p.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDR",
                   help="run the episodes as Ray tasks that write into --out (shared storage on a cluster): "
                        "on a local one-node Ray (no ADDR; --workers CPUs if given, else every core) or on the "
                        "running cluster at ADDR (`ray start --head` prints it); same seed, same episodes as "
                        "local workers")


def add_object_perception(p, needs: str) -> None:
    """``--object-perception NAME``: the object's true centre with 2 mm noise, or a camera object estimator
    (checked by the library, so a bad name is one line); ``needs`` says what the estimators need."""
    p.add_argument("--object-perception", default="truth", metavar="NAME",
                   help=f"where the object's position and extent come from: {', '.join(OBJECT_PERCEPTIONS)}; truth "
                        "(default) is the true centre with 2 mm noise, the others estimate it from the depth camera's "
                        "frame each step (centroid: the paper's; mesh_fit: the object's model fitted to its points, "
                        f"the most accurate; hingelab.perception.object_estimate){needs}")


def add_object_noise(p) -> None:
    """``--object-noise gaussian|fitted:NAME`` and ``--object-noise-model PATH``: ToolPick-v0's ``object_noise``
    (checked by the library, so a bad value is one line)."""
    p.add_argument("--object-noise", default=OBJECT_NOISE_GAUSSIAN, metavar="MODE",
                   help="the error on the observed object: gaussian (default: the true centre and extent with 2 mm "
                        "noise) or fitted:NAME, the depth camera's error without rendering, drawn from the fitted "
                        "model of estimator NAME (centroid, ray_corrected, primitive_fit, mesh_fit, or temporal_NAME: "
                        "hingelab.perception.object_noise_model), e.g. fitted:ray_corrected")
    p.add_argument("--object-noise-model", default=None, metavar="PATH",
                   help="the fitted model for --object-noise fitted:NAME (default "
                        f"{OBJECT_NOISE_MODEL.relative_to(REPO_ROOT)}, made by hingelab diagnose object-noise-fit)")


class _MaxMeshMb(argparse.Action):
    """Sets ``$HINGELAB_MAX_MESH_MB`` when parsed: meshes are loaded wherever a scene is built (the
    command's process, its env subprocesses, its Ray workers), and all of them inherit the environment."""

    def __call__(self, parser, namespace, value, option_string=None):
        if not value > 0 or value == float("inf"):
            parser.error(f"{option_string} must be a positive number of MB, not {value:g}")
        os.environ[MAX_MESH_MB_ENV] = repr(value)
        setattr(namespace, self.dest, value)


def add_max_mesh_mb(p) -> None:
    """``--max-mesh-mb MB``: the largest ``mesh:PATH`` file read (a larger one is refused before it is read)."""
    p.add_argument("--max-mesh-mb", type=float, default=None, action=_MaxMeshMb, metavar="MB",
                   help=f"largest mesh:PATH file to read, in MB (default {DEFAULT_MAX_MESH_MB:g}, or "
                        f"${MAX_MESH_MB_ENV}); a larger file is refused before it is read")
