"""``hingelab trial``: the hierarchical policy on a robot, trial by trial, each trial one MCAP episode.

A trial: the robot sets the scene up (``Robot.start_trial``; the stand-in resets, a real rig waits
for the operator), then up to ``max_steps`` control periods of 50 ms: the controller reads the
robot (camera frame, joints, object estimate) and commands it. Attempts: a grasp that lifts the
object and loses it ends an attempt; the policy goes on with the next one within the same steps
(as in ``eval high``).

The outcome: without ``--operator`` the simulation's verdict (the object within 1 cm of the
target; ``Robot.verdict``); with it, the operator is asked after each attempt on the terminal,
``[s]uccess``, ``[f]ailure`` or ``[a]bort``, and the answers are the episode's ``success``,
``attempt`` and ``first_attempt_success`` (``outcome_by``: ``operator``). A failure with steps left
lets the policy try again; an abort ends the trial (``failure_reason``: ``aborted``).

Each trial's episode (source ``stand_in`` or ``real``) holds per step the camera's tool cloud, the
tracked tool pose (``/tool/pose`` and ``/tf``), the hand's and the arm's joints, the latents, the
high-level action and latent goal, the object estimate and the target, and every ``depth_every``-th
control period the depth image (``/camera/depth``, 16-bit mm), the camera's pose in hand_base and,
once, its calibration. The stand-in adds the simulator's truth (``/sim/privileged``). With a camera
object estimator (``object_perception``, the stand-in's choice) each step also records the estimate the
controller was given, this frame's visible points and flag (``/object/estimate``, ``/object/points``) and the
object's true centre beside it (the truth of the step's time; the estimate is the reading's, which the
stand-in's latency delays). A trial whose robot has never reported an object estimate ends at once
(``no_object_estimate``), recorded like one whose camera gave no tool cloud (``no_camera_cloud``). The file is
flushed every ``FLUSH_EVERY`` steps and kept as ``.partial`` if the trial is cut off (Ctrl-C, a
crash): ``hingelab datasets recover`` salvages it.
"""

from __future__ import annotations

import inspect
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from hingelab.analysis.pick_table import FAILURE_REASONS, pick_rates
from hingelab.envs.recording import object_metadata, object_perception_metadata, platform_pose, privileged_fields
from hingelab.episodes import EpisodeWriter, create_dataset
from hingelab.episodes import schemas as S
from hingelab.errors import ConfigError
from hingelab.folder_lock import is_empty
from hingelab.perception.object_perception import TRUTH, check_object_perception
from hingelab.perception.observed_tool_pose import check_tool_position
from hingelab.perception.tool_perception import CALIBRATED, check_hand_eye
from hingelab.policies.high_level import SHIPPED_HIGH_LEVEL
from hingelab.robot import stand_in  # noqa: F401  (registers the "sim" robot)
from hingelab.robot.controller import (
    NO_OBJECT_ESTIMATE,
    CheckpointHighLevel,
    HierarchicalController,
    ScriptedStandInHighLevel,
    Step,
)
from hingelab.robot.interface import ROBOTS, Robot, RobotReadings
from hingelab.seeds import STRIDE, TRIALS_BASE, trial_seed
from hingelab.sim import names
from hingelab.sim.mesh_objects import object_label
from hingelab.sim.object_families import episode_record
from hingelab.sim.scripted import platform_in_hand

FLUSH_EVERY = 20  # steps: what a crash can lose at most
ANSWERS = {"s": "success", "success": "success", "f": "failure", "failure": "failure", "a": "abort", "abort": "abort"}


@dataclass(frozen=True)
class TrialConfig:
    object: str = "sphere"
    size: float = 0.02
    trials: int = 12
    seed: int = 0
    max_steps: int = 200
    depth_every: int = 4  # record the depth image every this many steps (5 Hz at 20 Hz control)
    operator: bool = False
    object_perception: str = TRUTH  # where the robot's object estimate comes from (the stand-in's choice)
    tool_position: str | None = None  # ToolPick-v0's form of the tool pose; None: what the policy trained on
    hand_eye: str = CALIBRATED  # the camera pose as calibrated, or refined on the robot's points (the stand-in's)

    def __post_init__(self):
        check_object_perception(self.object_perception)
        check_hand_eye(self.hand_eye)
        if self.tool_position is not None:
            check_tool_position(self.tool_position)
        if self.trials < 1 or self.max_steps < 1 or self.depth_every < 1:
            raise ConfigError(f"--trials, the step limit and --depth-every must be at least 1: {asdict(self)}")


def ask_operator(question: str, read=input, write=print) -> str:
    """One of success, failure, abort, asked until the answer is one of them (end of input: abort)."""
    while True:
        try:
            answer = read(question).strip().lower()
        except EOFError:
            write("no answer (end of input): the trial is aborted")
            return "abort"
        if answer in ANSWERS:
            return ANSWERS[answer]
        write("answer s (success), f (failure) or a (abort)")


def _record_step(writer, robot: Robot, readings: RobotReadings, step: Step, t: float, index: int,
                 config: TrialConfig) -> None:
    sample = step.sample
    pose = None
    if sample is not None:
        pose = (sample.position[0], Rotation.from_matrix(sample.rotation[0]).as_quat())
    privileged = platform = None
    if hasattr(robot, "sim"):  # the stand-in knows the truth; a real rig does not
        privileged = privileged_fields(robot.sim.reader.read(robot.sim.data))
        platform = platform_pose(platform_in_hand(robot.sim.model, robot.sim.data, robot.sim.reader.hand_body))
    writer.write_step(t, points_hand=step.cloud, tool_pose_hand=pose, joint_position=readings.hand_position,
                      joint_velocity=readings.hand_velocity,
                      latent_z=None if sample is None else sample.z[0],
                      latent_z_smoothed=None if sample is None else sample.z_smoothed[0],
                      action=step.action, goal_z=step.z_goal, object_position_hand=step.object_hand,
                      target_position_hand=step.target_hand, privileged=privileged, platform_hand=platform)
    writer.write_arm_joints(t, robot.arm_joint_names, readings.arm_position, readings.arm_velocity)
    if getattr(robot, "object_perception", TRUTH) != TRUTH:
        _record_object_estimate(writer, robot, readings, t)
    if index % config.depth_every == 0:
        frame = readings.frame
        writer.write_camera(t, frame.depth, frame.intrinsics, frame.camera_rotation, frame.camera_position,
                            calibration=index == 0)


def _record_object_estimate(writer, robot: Robot, readings: RobotReadings, t: float) -> None:
    """The object estimate the controller got (hand_base, through the reading's hand pose; NaN before the first),
    its frame's points and flag, and the stand-in's truth now."""
    centre = readings.object_centre
    points = readings.object_points
    truth = None
    if hasattr(robot, "true_object_centre"):  # a simulated robot knows the truth; a real rig does not
        truth = robot.pick._to_hand(robot.true_object_centre())
    writer.write_object_estimate(
        t, estimator=robot.object_perception,
        position=np.full(3, np.nan) if centre is None else readings.to_hand(centre),
        extent=np.zeros(3) if readings.object_extent is None else readings.object_extent,
        n_points=0 if points is None else len(points), fresh=points is not None, flag=readings.object_flag or "",
        true_position=truth,
        points=None if points is None else (readings.hand_rotation.T @ (points - readings.hand_translation).T).T)


def run_trial(robot: Robot, controller: HierarchicalController, writer, seed: int, config: TrialConfig,
              read=input, write=print, label: str = "") -> dict:
    """One trial into ``writer`` (open); returns its row: success, first_attempt_success, attempts, reason."""
    readings = robot.start_trial(seed)
    if not config.operator and robot.verdict() is None:
        raise ConfigError(f"the robot {type(robot).__name__} cannot judge a trial's outcome; run with --operator")
    controller.reset(readings, seed)
    start = readings.stamp_s
    attempt, outcome, reason, steps = 1, None, None, 0
    while steps < config.max_steps:
        step = controller.act(readings)
        _record_step(writer, robot, readings, step, readings.stamp_s - start, steps, config)
        if step.flag == NO_OBJECT_ESTIMATE:
            outcome, reason = "failure", NO_OBJECT_ESTIMATE
            write(f"{label}: the robot has not estimated the object ({readings.object_flag}); the trial ends")
            break
        if step.flag is not None:
            outcome, reason = "failure", "no_camera_cloud"
            write(f"{label}: the camera gave no tool cloud ({step.flag}); the trial ends")
            break
        readings = robot.command(step.hand_velocity, step.hand_changes)
        steps += 1
        verdict = robot.verdict()
        if config.operator:
            if verdict is None:  # a real rig: nothing tells an attempt's end; the operator judges at the step limit
                attempt_over = steps >= config.max_steps
            else:
                attempt_over = verdict.done or verdict.attempt > attempt or steps >= config.max_steps
            if attempt_over:
                answer = ask_operator(f"{label}, attempt {attempt}: [s]uccess, [f]ailure or [a]bort? ", read, write)
                if answer != "failure":
                    outcome, reason = answer, (None if answer == "success" else "aborted")
                    break
                if verdict is None or verdict.done or steps >= config.max_steps:
                    outcome = "failure"
                    reason = (verdict.failure_reason if verdict is not None else None) or "operator_failure"
                    break
                attempt += 1
        elif verdict.done:
            outcome = "success" if verdict.success else "failure"
            attempt, reason = verdict.attempt, verdict.failure_reason
            break
    if outcome is None:  # the step limit without a verdict that ended it
        verdict = robot.verdict()
        success = bool(verdict and verdict.success)
        outcome, reason = ("success" if success else "failure"), (None if success else "timeout")
        attempt = verdict.attempt if verdict else attempt
    success = outcome == "success"
    if not config.operator:
        verdict = robot.verdict()
        first = bool(verdict.first_attempt_success) if verdict else success and attempt == 1
    else:
        first = success and attempt == 1
    facts = robot.episode_facts() if hasattr(robot, "episode_facts") else {}  # e.g. the stand-in's hand-eye fit
    writer.set_outcome(success, failure_reason=None if success else (reason or "timeout"), attempt=attempt,
                       first_attempt_success=first, outcome_by="operator" if config.operator else "simulation",
                       **facts)
    return {"seed": seed, "success": success, "first_attempt_success": first, "attempts": attempt,
            "failure_reason": "" if success else (reason or "timeout"), "steps": steps}


def run_trials(robot: Robot, controller: HierarchicalController, dataset_dir, config: TrialConfig,
               read=input, write=print, progress: bool = True, extra_metadata: dict | None = None) -> pd.DataFrame:
    """``config.trials`` trials into the dataset ``dataset_dir`` (made by ``create_dataset``); their table."""
    rows = []
    bar = tqdm(range(config.trials), desc=f"trials {config.object} {100 * config.size:g} cm", unit="trial",
               disable=not progress or config.operator)
    for index in bar:
        seed = trial_seed(config.seed, index)
        writer = EpisodeWriter(dataset_dir, source=robot.source, task="ToolPick trial",
                               object=object_label(config.object), seed=seed, action_level="high",
                               joint_names=names.HAND_ACTUATORS, flush_every_steps=FLUSH_EVERY,
                               keep_partial_on_error=True,
                               extra_metadata={"object_size": config.size, "trial": index, S.KEY_SUCCESS_VERDICT:
                                               "operator" if config.operator else "object_within_1cm",
                                               **object_perception_metadata(robot),
                                               **(extra_metadata or {}),
                                               # a family's draw for this seed: what the stand-in's env draws
                                               **object_metadata(episode_record(config.object, config.size, seed))})
        with writer:
            row = run_trial(robot, controller, writer, seed, config, read=read, write=write,
                            label=f"trial {index + 1}/{config.trials}")
        rows.append({"trial": index, **row})
        bar.set_postfix(success=f"{sum(r['success'] for r in rows) / len(rows):.2f}")
    return pd.DataFrame(rows)


@dataclass
class TrialSession:
    out: Path
    label: str  # the high-level policy
    low_level: str
    rows: pd.DataFrame  # one row per trial (trials.csv)
    table: pd.DataFrame  # the pick table's rates with Wilson intervals (table.csv)
    summary: str


def high_level_for(robot: Robot, policy=None, low_level: str | None = None, warn=print):
    """The high level a trial runs: ``policy`` (a checkpoint), else the shipped one, else (on the stand-in,
    without a shipped policy) the scripted high level, said through ``warn``."""
    if policy is None and not SHIPPED_HIGH_LEVEL.exists():
        warn(f"hingelab trial: warning: no shipped high-level policy ({SHIPPED_HIGH_LEVEL}); the stand-in runs the "
             "scripted high level (the heuristic's motion over the low-level policy) instead")
        return ScriptedStandInHighLevel(robot, low_level)
    return CheckpointHighLevel(policy or SHIPPED_HIGH_LEVEL, low_level)


def run_trial_session(robot_name: str, config: TrialConfig, out, policy=None, low_level: str | None = None,
                      progress: bool = True, read=input, write=print, warn=print) -> TrialSession:
    """``hingelab trial``: ``config.trials`` trials on the robot registered as ``robot_name`` into the new
    dataset ``out``, then ``trials.csv`` and ``table.csv``. A Ctrl-C keeps the trial under way as a
    ``.partial`` file (said through ``warn``) and the finished trials in ``out``."""
    out = Path(out)
    if robot_name not in ROBOTS:
        raise ConfigError(f"no robot {robot_name!r}; the robots: {', '.join(ROBOTS)}")
    if not is_empty(out):
        raise ConfigError(f"{out} exists and is not empty; give a new folder to --out")
    make, options = ROBOTS[robot_name], {}
    if config.object_perception != TRUTH:
        if "object_perception" not in inspect.signature(make).parameters:
            raise ConfigError(f"the robot {robot_name!r} has its own object estimate; --object-perception is for the "
                              "stand-in (--robot sim)")
        options["object_perception"] = config.object_perception
    if config.hand_eye != CALIBRATED:
        if "hand_eye" not in inspect.signature(make).parameters:
            raise ConfigError(f"the robot {robot_name!r} has its own camera calibration; --hand-eye is for the "
                              "stand-in (--robot sim)")
        options["hand_eye"] = config.hand_eye
    robot = make(config.object, config.size, config.max_steps, **options)  # a bad object: an error before files
    try:
        high = high_level_for(robot, policy, low_level, warn=warn)
        tool_position = config.tool_position or getattr(high, "tool_position", "observed")
        anchored = {"tool_position": tool_position} if tool_position != "observed" else {}
        card = {"robot": robot_name, "policy": high.label, "low_level": high.low_level, "object": config.object,
                "size": config.size, "trials": config.trials, "max_steps": config.max_steps,
                "operator": config.operator, "depth_every": config.depth_every,
                "seeds": f"{TRIALS_BASE} + seed * {STRIDE} + trial",
                **({"object_perception": config.object_perception} if config.object_perception != TRUTH else {}),
                **({"hand_eye": config.hand_eye} if config.hand_eye != CALIBRATED else {}), **anchored}
        create_dataset(out, name=f"trial-{config.object}-{config.size * 100:g}cm", source=robot.source,
                       config=card, seed=config.seed,
                       description=f"hingelab trial on the {robot_name} robot: {high.label} over {high.low_level}, "
                                   f"{config.object} {config.size * 100:g} cm")
        try:
            controller = HierarchicalController(high, tool_position=tool_position)
            rows = run_trials(robot, controller, out, config, read=read, write=write, progress=progress,
                              extra_metadata={"policy": high.label, "low_level": high.low_level, **anchored})
        except KeyboardInterrupt:
            partial = sorted((out / "episodes").glob("*.partial"))
            where = f" ({partial[-1]})" if partial else ""
            warn(f"hingelab trial: interrupted; the trial under way is kept as a .partial file{where}: salvage it "
                 f"with `hingelab datasets recover FILE --out NEWFILE`; the finished trials are in {out}")
            raise
    finally:
        robot.close()
    rows.to_csv(out / "trials.csv", index=False)
    row = {"object": config.object, "size_cm": 100 * config.size, "trials": len(rows), **pick_rates(rows)}
    table = pd.DataFrame([row])
    table.to_csv(out / "table.csv", index=False)
    failures = ", ".join(f"{r} {row[f'failures_{r}']}" for r in FAILURE_REASONS if row[f"failures_{r}"])
    other = rows.loc[~rows["success"] & ~rows["failure_reason"].isin(FAILURE_REASONS), "failure_reason"]
    if len(other):
        failures = ", ".join(filter(None, [failures, *(f"{k} {v}" for k, v in other.value_counts().items())]))
    judged = "the operator" if config.operator else "the simulation (object within 1 cm of the target)"
    summary = (f"{len(rows)} trials of {high.label} over {high.low_level} on the {robot_name} robot, {config.object} "
               f"{config.size * 100:g} cm, judged by {judged}: first attempt {int(row['first_attempt_successes'])}/"
               f"{len(rows)} = {row['first_attempt_success_rate']:.2f} [{row['first_attempt_ci_low']:.2f}, "
               f"{row['first_attempt_ci_high']:.2f}], with further attempts {int(row['successes'])}/{len(rows)} = "
               f"{row['success_rate']:.2f} [{row['ci_low']:.2f}, {row['ci_high']:.2f}]; failures: "
               f"{failures or 'none'}. Dataset, trials.csv, table.csv in {out}.")
    return TrialSession(out, high.label, high.low_level, rows, table, summary)

