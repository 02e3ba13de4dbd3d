"""``hingelab --help`` and ``hingelab COMMAND --help`` import no heavy library: the parser is built from light
modules (``hingelab.cli.main``), and ``main`` leaves the MuJoCo check to commands that run."""

import json
import os
import subprocess
import sys
from pathlib import Path

PLATFORM = Path(__file__).resolve().parents[1] / "platform"
HEAVY = ("torch", "mujoco", "stable_baselines3", "ray", "pandas", "numpy", "gymnasium")
# every verb, the sub-commands with flags of their own, and train's levels (their flags come from the learners)
HELP_LINES = [[], ["generate", "clouds"], ["generate", "heuristic"], ["train"], ["train", "encoder"], ["train", "low"],
              ["train", "high"], ["train", "flat"], ["train", "high", "--learner", "phase-clone"],
              ["train", "high", "--learner", "residual-sac"], ["sweep"],
              ["reproduce"], ["eval", "low"], ["eval", "high"], ["eval", "perception"], ["trial"],
              ["diagnose", "bias"], ["compose", "low"], ["view"], ["report"], ["datasets", "export"],
              ["datasets", "import-ros2"], ["checkpoints", "convert"], ["bench"], ["demo"]]

PROBE = """
import contextlib, io, json, sys
from hingelab.cli.main import main
for words in json.loads(sys.argv[1]):
    with contextlib.redirect_stdout(io.StringIO()) as out:
        try:
            main([*words, "--help"])
        except SystemExit as exc:
            assert exc.code == 0, (words, exc.code)
    assert "usage: hingelab" in out.getvalue(), words
print(json.dumps(sorted(name for name in json.loads(sys.argv[2]) if name in sys.modules)))
"""


def test_help_imports_no_heavy_library():
    """One fresh interpreter asks every command for its help; none of them loads torch, MuJoCo,
    stable-baselines3, Ray or pandas (each costs a second or more, and MuJoCo with a bad MUJOCO_GL fails)."""
    env = {**os.environ, "PYTHONPATH": str(PLATFORM), "MUJOCO_GL": "no-such-backend"}
    done = subprocess.run([sys.executable, "-c", PROBE, json.dumps(HELP_LINES), json.dumps(HEAVY)],
                          capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.strip().splitlines()[-1]) == []


def test_names_mirror_the_registries():
    """The names ``--help`` lists without loading the library are the registries' own."""
    from hingelab.cli import names
    from hingelab.episodes.export import EXPORTERS
    from hingelab.perception import object_noise_model
    from hingelab.perception.object_perception import OBJECT_PERCEPTIONS
    from hingelab.perception.observed_tool_pose import TOOL_POSITIONS
    from hingelab.perception.tool_perception import HAND_EYE
    from hingelab.policies import baseline_names
    from hingelab.robot import stand_in  # noqa: F401  (registers sim)
    from hingelab.robot.interface import ROBOTS
    from hingelab.rollouts import bias_tolerance, noise_tolerance
    from hingelab.ros2 import bag_export  # noqa: F401  (registers ros2)
    from hingelab.ros2.object_from_cloud import CLOUD_ESTIMATORS, DEFAULT_ESTIMATOR

    assert names.EXPORT_FORMATS == tuple(EXPORTERS)
    assert names.OBJECT_PERCEPTIONS == OBJECT_PERCEPTIONS
    assert (names.OBJECT_ESTIMATORS, names.OBJECT_FROM_CLOUD_DEFAULT) == (CLOUD_ESTIMATORS, DEFAULT_ESTIMATOR)
    assert (names.OBJECT_NOISE_GAUSSIAN, names.OBJECT_NOISE_MODEL) == (object_noise_model.GAUSSIAN,
                                                                      object_noise_model.DEFAULT_MODEL)
    assert names.BASELINES == {level: baseline_names(level) for level in ("low", "high")}
    assert names.ROBOTS == tuple(ROBOTS)
    assert names.TOOL_POSITIONS == TOOL_POSITIONS
    assert names.HAND_EYE == HAND_EYE
    assert names.NOISE_LEVELS == noise_tolerance.DEFAULT_LEVELS
    assert names.BIAS_LEVELS == bias_tolerance.DEFAULT_LEVELS


def test_eval_baseline_checked_in_one_line(tmp_path, capsys):
    """--baseline is checked against the policies' registry when the command runs (not by argparse)."""
    from hingelab.cli.main import main

    assert main(["eval", "high", "--baseline", "no-such", "--out", str(tmp_path / "out"), "--episodes", "1"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "scripted-feedback" in err
    assert not (tmp_path / "out").exists()


REGISTRATION = """
import sys
import hingelab
assert "gymnasium" not in sys.modules and "numpy" not in sys.modules, "import hingelab loaded Gymnasium"
{first}
import gymnasium as gym
ids = ("hingelab/ToolShape-v0", "hingelab/ToolPick-v0", "hingelab/ToolPickFlat-v0")
print(all(i in gym.registry for i in ids), gym.spec("hingelab/ToolShape-v0").max_episode_steps)
"""


def test_the_envs_are_registered_however_gymnasium_is_imported():
    """``import hingelab`` leaves Gymnasium (and NumPy) unloaded; the envs are registered as Gymnasium's import
    ends, whether it is imported as the package, through a submodule, after a mere look-up, or before hingelab."""
    env = {**os.environ, "PYTHONPATH": str(PLATFORM), "MUJOCO_GL": "no-such-backend"}
    looked_up = "import importlib.util\nassert importlib.util.find_spec('gymnasium') is not None"
    for first in ("", "from gymnasium.envs.registration import registry", "import gymnasium.spaces", looked_up):
        done = subprocess.run([sys.executable, "-c", REGISTRATION.format(first=first)], capture_output=True,
                              text=True, env=env, timeout=120)
        assert done.returncode == 0, done.stderr
        assert done.stdout.split() == ["True", "50"], (first, done.stdout)
    before = "import gymnasium as gym\nimport hingelab\nprint('hingelab/ToolPick-v0' in gym.registry)"
    done = subprocess.run([sys.executable, "-c", before], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "True", done.stderr
