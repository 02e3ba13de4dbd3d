"""The names that flags list in ``--help``, kept here so the parser imports no library.

Each tuple mirrors a registry that lives in a module importing torch, MuJoCo or pandas; the library
checks a given name against the registry itself (one line naming the choices), and
``tests/test_fast_help.py`` checks that every tuple equals its registry.
"""

from __future__ import annotations

from hingelab.paths import ANALYSIS_DIR

# hingelab.episodes.export.EXPORTERS (with hingelab.ros2.bag_export's ros2)
EXPORT_FORMATS = ("minari", "lerobot", "ros2")
# hingelab.perception.object_perception.OBJECT_PERCEPTIONS: truth, then the camera estimators
OBJECT_PERCEPTIONS = ("truth", "centroid", "ray_corrected", "primitive_fit", "mesh_fit")
# hingelab.ros2.object_from_cloud.CLOUD_ESTIMATORS and DEFAULT_ESTIMATOR
OBJECT_ESTIMATORS = ("centroid", "ray_corrected", "primitive_fit")
OBJECT_FROM_CLOUD_DEFAULT = "ray_corrected"
# hingelab.perception.object_noise_model.GAUSSIAN and DEFAULT_MODEL
OBJECT_NOISE_GAUSSIAN = "gaussian"
OBJECT_NOISE_MODEL = ANALYSIS_DIR / "objects" / "noise-model" / "object_noise_model.json"
# hingelab.policies.baseline_names(level)
BASELINES = {"low": ("hold-still", "synergy"),
             "high": ("heuristic", "scripted", "scripted-observed", "scripted-perceived", "scripted-feedback",
                      "random")}
# hingelab.rollouts.noise_tolerance.DEFAULT_LEVELS and bias_tolerance.DEFAULT_LEVELS: diagnose's levels
NOISE_LEVELS = (0.02, 0.05, 0.1, 0.2, 0.3)
BIAS_LEVELS = (0.01, 0.025, 0.05)
# hingelab.perception.observed_tool_pose.TOOL_POSITIONS: eval high's and trial's --tool-position
TOOL_POSITIONS = ("observed", "anchored", "relative", "nominal")
# hingelab.perception.tool_perception.HAND_EYE: trial's --hand-eye (the first is the default)
HAND_EYE = ("calibrated", "refined", "exact")
# hingelab.robot.interface.ROBOTS (hingelab.robot.stand_in registers sim)
ROBOTS = ("sim",)
