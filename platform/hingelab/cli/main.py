"""Entry point of the ``hingelab`` command.

Each verb lives in its own module under ``hingelab.cli`` with two functions:
``add_parser(subparsers)`` registers the verb and its options, and the parser's
``func`` default runs it. Errors a user can fix are raised as ``HingelabError``
and printed as one line; everything else propagates with its traceback.

Building the parser imports no heavy library (torch, MuJoCo, stable-baselines3, Ray, pandas), so
``hingelab --help`` and ``hingelab COMMAND --help`` answer at once: a verb module imports the library it
runs inside its run functions, and what its flags need (defaults, choices) comes from light modules
(``tests/test_fast_help.py``).
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import os
import sys

from hingelab.errors import HingelabError

# Verb modules in the order ``hingelab --help`` lists them.
VERB_MODULES = [
    "hingelab.cli.demo",
    "hingelab.cli.generate",
    "hingelab.cli.train",
    "hingelab.cli.sweep",
    "hingelab.cli.reproduce",
    "hingelab.cli.eval",
    "hingelab.cli.trial",
    "hingelab.cli.diagnose",
    "hingelab.cli.compose",
    "hingelab.cli.view",
    "hingelab.cli.report",
    "hingelab.cli.datasets",
    "hingelab.cli.checkpoints",
    "hingelab.cli.bench",
]


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The whole command line; ``argv`` lets a verb build its flags for the command line at hand
    (``hingelab train high --learner NAME`` gets that learner's flags)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(
        prog="hingelab",
        description=(
            "Hierarchical RL of articulated-tool use with a multifingered hand: "
            "generate episode datasets, train from them, view and report on them."
        ),
    )
    subparsers = parser.add_subparsers(title="commands", metavar="COMMAND")
    for name in VERB_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # verb not built yet
                continue
            raise
        if "argv" in inspect.signature(module.add_parser).parameters:
            module.add_parser(subparsers, argv)
        else:
            module.add_parser(subparsers)
    return parser


def mujoco_importable() -> str | None:
    """None, or the one-line reason MuJoCo does not import: a ``MUJOCO_GL`` it cannot use fails at import."""
    try:
        import mujoco  # noqa: F401  (the check itself: can MuJoCo be imported with this MUJOCO_GL)
    except Exception as exc:  # RuntimeError (an unknown value) or AttributeError (a backend's library missing)
        if "MUJOCO_GL" not in os.environ:
            raise
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        return (f"MuJoCo does not load with MUJOCO_GL={os.environ['MUJOCO_GL']} ({first}); set MUJOCO_GL to a "
                "backend this machine has: egl (headless), osmesa (Mesa's software renderer) or glfw (a display)")
    return None


def main(argv: list[str] | None = None) -> int:
    parser = build_parser(argv)
    args = parser.parse_args(argv)  # --help ends here, before anything heavy is imported
    args.argv = list(sys.argv[1:] if argv is None else argv)  # the command line (a resume hint repeats it)
    if not hasattr(args, "func"):
        parser.print_help()
        return 2
    problem = mujoco_importable()
    if problem:
        print(f"hingelab: error: {problem}", file=sys.stderr)
        return 1
    from hingelab.episodes.dataset import corrupt_policy  # with the library the command runs (pandas)

    try:
        with corrupt_policy(getattr(args, "on_corrupt", "stop")):
            result = args.func(args)
    except HingelabError as exc:
        print(f"hingelab: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("hingelab: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader went away (`hingelab datasets info X | head`): stop quietly
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # so the interpreter's final flush does not raise again
        return 141
    return int(result or 0)


if __name__ == "__main__":
    sys.exit(main())
