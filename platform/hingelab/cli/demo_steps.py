"""The steps of ``hingelab demo`` (``hingelab.cli.demo`` runs them in order): each runs one part of the pipeline
on shipped defaults, prints what it measured and returns it."""

from __future__ import annotations

import json
import os
import shutil
import time

import numpy as np
import pandas as pd

from hingelab.analysis import build_report
from hingelab.episodes import create_dataset
from hingelab.episodes.dataset import Dataset
from hingelab.paths import ANALYSIS_DIR, DATASETS_DIR
from hingelab.policies.high_level import SHIPPED_HIGH_LEVEL
from hingelab.policies.loading import baseline_names
from hingelab.policies.low_level import SHIPPED_LOW_LEVEL
from hingelab.robot.controller import CheckpointHighLevel, HierarchicalController
from hingelab.robot.stand_in import StandInRobot
from hingelab.robot.trial import TrialConfig, run_trials
from hingelab.rollouts.evaluation import evaluate_high, evaluate_low
from hingelab.rollouts.heuristic_demos import HeuristicRunConfig, generate_heuristic_dataset, summarize
from hingelab.ros2.bag_export import export_ros2
from hingelab.ros2.bag_import import import_bags
from hingelab.ros2.rig_bag import RigBagSpec, write_rig_bag
from hingelab.sim import scripted
from hingelab.sim.core import SimCore
from hingelab.sim.finger_synergy import FingerSynergy
from hingelab.sweeps.runner import SWEEP_CSV, run_sweep, summary
from hingelab.sweeps.spec import load_sweep
from hingelab.viewers.view import view


def step_platform(seed: int) -> dict:
    """the robot platform."""
    synergy = FingerSynergy.load()
    sim = SimCore("tool_pick", seed=seed)
    sim.reset()
    started = time.perf_counter()

    hold = scripted.hold(sim, 2.0)
    print(f"  hold 2 s in the grasp keyframe: tool moved {hold.max_mm:.2f} mm, {hold.max_deg:.2f} deg in the hand")

    sim.reset()
    work = scripted.work_tool_with_fingers(sim, synergy)
    gap = lambda theta: 1000 * scripted.TOOL_TIP_X * np.sin(theta)  # noqa: E731
    print(f"  fingers alone: hinge {work.hinge_min:.3f} .. {work.hinge_max:.3f} rad "
          f"(tips {gap(max(work.hinge_min, 0)):.1f} .. {gap(work.hinge_max):.1f} mm apart), "
          f"tool moved at most {work.drift.max_mm:.1f} mm, {work.drift.max_deg:.1f} deg")

    sim.reset()
    top, center = scripted.platform_top(sim.model), scripted.platform_center(sim.model)
    drift = scripted.drift_from(sim)
    errors, collided = [], False
    for dx, dy in [(-0.05, -0.05), (0.05, -0.05), (0.05, 0.05), (-0.05, 0.05), (0.0, 0.0)]:
        move = scripted.move_grip_to(sim, np.array([center[0] + dx, center[1] + dy, top + 0.01]), drift=drift)
        errors.append(move.error_m)
        collided |= move.table_collision
    print(f"  arm carries the tips over the 10 x 10 cm area (corners + centre, 1 cm above the platform): "
          f"worst error {1000 * max(errors):.2f} mm, table collision: {'yes' if collided else 'no'}, "
          f"tool moved {drift.max_mm:.1f} mm in the hand")

    sim.reset()
    lift = scripted.grasp_and_lift(sim, synergy, object_size=0.02, lift=0.05)
    print(f"  privileged hinge command: closed on the 1 cm sphere at {lift.hinge_at_grasp:.3f} rad, "
          f"lifted it {100 * lift.lifted_m:.1f} cm by friction ({lift.tool_object_contacts} tip contacts)")
    return {
        "hold_drift_mm": hold.max_mm, "hold_drift_deg": hold.max_deg,
        "finger_hinge_range_rad": [work.hinge_min, work.hinge_max],
        "finger_drift_mm": work.drift.max_mm, "finger_drift_deg": work.drift.max_deg,
        "reach_worst_error_mm": 1000 * max(errors), "reach_table_collision": collided,
        "lift_cm": 100 * lift.lifted_m, "wall_time_s": time.perf_counter() - started,
    }


DEMO_DATASET = DATASETS_DIR / "demo_heuristic"
DEMO_OUT = ANALYSIS_DIR / "demo"


def step_heuristic_demos(seed: int) -> dict:
    """heuristic demos on ToolPick-v0, recorded as an MCAP dataset."""

    shutil.rmtree(DEMO_DATASET, ignore_errors=True)  # the demo's own output: remade each run
    config = HeuristicRunConfig(episodes=3, seed=seed)
    started = time.perf_counter()
    summaries = generate_heuristic_dataset(DEMO_DATASET, config, progress=False)
    print(f"  {DEMO_DATASET}: {summarize(summaries, time.perf_counter() - started)}")
    return {"dataset": str(DEMO_DATASET), "episodes": len(summaries),
            "success_rate": float(np.mean([s.success for s in summaries]))}


DEMO_LOW_LEVEL_DATASET = DATASETS_DIR / "demo_low_level"


def step_low_level_policy(seed: int) -> dict:
    """The shipped low-level policy shapes the tweezer to latent goals (ToolShape-v0), as `eval low` runs it."""
    shutil.rmtree(DEMO_LOW_LEVEL_DATASET, ignore_errors=True)
    started = time.perf_counter()
    result = evaluate_low(SHIPPED_LOW_LEVEL, out=DEMO_LOW_LEVEL_DATASET, episodes=3, seed=seed, progress=False,
                          name="demo-low-level",
                          description="hingelab demo: the shipped low-level policy toward 3 reachable goals")
    threshold = result.details["success_threshold"]
    rows = result.episodes.to_dict("records")
    for row in rows:
        print(f"  goal opening {row['goal_opening_rad']:.3f} rad: hinge reached {row['final_hinge_rad']:.3f} rad, "
              f"tip-gap error {row['tip_gap_error_mm']:.1f} mm, latent distance over the last 0.5 s "
              f"{row['settled_latent_distance']:.3f} (threshold {threshold:.3f}): "
              f"{'success' if row['success'] else 'failure'}, tool moved at most {row['tool_drift_mm_max']:.1f} mm")
    overall = result.table.iloc[-1]
    # the env's verdict (settled over the last 0.5 s), as each episode records it: report counts the same
    print(f"  {SHIPPED_LOW_LEVEL.name}: success {int(overall['successes'])}/{len(rows)} (settled over the last 0.5 s) "
          f"in {time.perf_counter() - started:.1f} s, recorded in {DEMO_LOW_LEVEL_DATASET}")
    return {"dataset": str(DEMO_LOW_LEVEL_DATASET), "episodes": len(rows), "successes": int(overall["successes"]),
            "success_rate": float(overall["success_rate"]),
            "last_step_success_rate": float(overall["last_step_success_rate"]),
            "tip_gap_error_mm": [r["tip_gap_error_mm"] for r in rows]}


DEMO_HIERARCHY_DATASET = DATASETS_DIR / "demo_scripted_hierarchy"
DEMO_LEARNED_DATASET = DATASETS_DIR / "demo_learned_hierarchy"
HIERARCHY_EPISODES = 2


def _pick_sphere(policy, label: str, dataset, seed: int, name: str, description: str) -> dict:
    """``HIERARCHY_EPISODES`` episodes of ``policy`` (a checkpoint or a baseline's name) on ToolPick-v0 (2 cm
    sphere) over the shipped low-level policy, as `hingelab eval high` runs them, recorded into ``dataset``."""
    shutil.rmtree(dataset, ignore_errors=True)
    baseline = policy if policy in baseline_names("high") else None
    started = time.perf_counter()
    result = evaluate_high(None if baseline else policy, baseline=baseline, out=dataset, object="sphere", size=0.02,
                           episodes=HIERARCHY_EPISODES, seed=seed, low_level="policy", progress=False, name=name,
                           description=description)
    episodes = result.episodes
    for row in episodes.itertuples():
        outcome = "picked and lifted to the target" if row.success else f"failed ({row.failure_reason})"
        print(f"  episode {row.episode}: {outcome} in {row.length} steps, {row.attempts} attempt(s)")
    successes = int(episodes["success"].sum())
    print(f"  {label} over the shipped low-level policy: success {successes}/{len(episodes)} (object within 1 cm of "
          f"the target) in {time.perf_counter() - started:.1f} s, recorded in {dataset}")
    return {"dataset": str(dataset), "episodes": len(episodes), "successes": successes,
            "first_attempt_successes": int(episodes["first_attempt_success"].sum())}


def step_scripted_hierarchy(seed: int) -> dict:
    """The hierarchy with a scripted high level (the heuristic's arm motion, its hinge command as a latent
    goal) over the shipped low-level policy: the reference for the learned high level."""
    return _pick_sphere("scripted", "scripted high level", DEMO_HIERARCHY_DATASET, seed, "demo-scripted-hierarchy",
                        "hingelab demo: hingelab eval high --baseline scripted over the shipped low level")


def step_learned_hierarchy(seed: int) -> dict:
    """The shipped high-level policy (assets/checkpoints/high_level.zip) over the shipped low-level policy
    picks the sphere, as `hingelab eval high` runs it."""
    if not SHIPPED_HIGH_LEVEL.exists():
        shutil.rmtree(DEMO_LEARNED_DATASET, ignore_errors=True)
        print(f"  no shipped high-level policy ({SHIPPED_HIGH_LEVEL}) yet: step skipped")
        return {"skipped": True}
    return _pick_sphere(SHIPPED_HIGH_LEVEL, SHIPPED_HIGH_LEVEL.name, DEMO_LEARNED_DATASET, seed,
                        "demo-learned-hierarchy",
                        "hingelab demo: the shipped high-level policy over the shipped low-level policy")


DEMO_TRIAL_DATASET = DATASETS_DIR / "demo_stand_in_trial"


def step_stand_in_trial(seed: int) -> dict:
    """one `hingelab trial` on the MuJoCo stand-in of the rig: the depth camera's frames through
    the camera cloud pipeline, the shipped hierarchy acting through the robot interface."""

    shutil.rmtree(DEMO_TRIAL_DATASET, ignore_errors=True)
    if not SHIPPED_HIGH_LEVEL.exists():
        print(f"  no shipped high-level policy ({SHIPPED_HIGH_LEVEL}) yet: step skipped")
        return {"skipped": True}
    started = time.perf_counter()
    create_dataset(DEMO_TRIAL_DATASET, name="demo-stand-in-trial", source="stand_in", seed=seed,
                   config={"robot": "sim", "object": "sphere", "size": 0.02, "trials": 1},
                   description="hingelab demo: hingelab trial --robot sim --object sphere --trials 1")
    robot = StandInRobot("sphere", 0.02)
    try:
        controller = HierarchicalController(CheckpointHighLevel(SHIPPED_HIGH_LEVEL))
        rows = run_trials(robot, controller, DEMO_TRIAL_DATASET, TrialConfig(trials=1, seed=seed), progress=False)
    finally:
        robot.close()
    row = rows.iloc[0]
    outcome = "picked and lifted to the target" if row.success else f"failed ({row.failure_reason})"
    print(f"  stand-in trial with the depth camera: {outcome} in {row.steps} steps, {row.attempts} attempt(s), "
          f"{time.perf_counter() - started:.1f} s; depth images, camera pose and clouds recorded in "
          f"{DEMO_TRIAL_DATASET}")
    return {"dataset": str(DEMO_TRIAL_DATASET), "success": bool(row.success), "steps": int(row.steps)}


DEMO_RIG_BAG = DATASETS_DIR / "demo_rig_bag"
DEMO_REAL_DATASET = DATASETS_DIR / "demo_real"
DEMO_REAL_EXPORT = DATASETS_DIR / "demo_real_ros2"


def step_ros2_bags(seed: int) -> dict:
    """a rig's ROS 2 bag (synthetic here: what `ros2 bag record` writes on the rig) imported as
    real episodes (hingelab datasets import-ros2), and those episodes exported back as ROS 2 bags."""

    for path in (DEMO_RIG_BAG, DEMO_REAL_DATASET, DEMO_REAL_EXPORT):  # the demo's own outputs: remade each run
        shutil.rmtree(path, ignore_errors=True)
    started = time.perf_counter()
    bag = write_rig_bag(DEMO_RIG_BAG, RigBagSpec(seed=seed))
    (summary,) = import_bags([DEMO_RIG_BAG], DEMO_REAL_DATASET)
    print(f"  {summary.line()}")
    exported = export_ros2(Dataset(DEMO_REAL_DATASET), DEMO_REAL_EXPORT)
    print(f"  {bag['messages']} messages of {DEMO_RIG_BAG} -> {len(summary.episodes)} real episodes "
          f"({summary.steps} steps) in {DEMO_REAL_DATASET} -> {exported.episodes} ROS 2 bags (MCAP) in "
          f"{DEMO_REAL_EXPORT}, in {time.perf_counter() - started:.1f} s")
    return {"bag": str(DEMO_RIG_BAG), "messages": bag["messages"], "dataset": str(DEMO_REAL_DATASET),
            "episodes": len(summary.episodes), "steps": summary.steps, "dropped": sum(summary.dropped.values()),
            "exported_bags": exported.episodes}


DEMO_SWEEP = DEMO_OUT / "sweep"
DEMO_SWEEP_FILE = DEMO_OUT / "demo_sweep.toml"
# a toy budget: the sweep's machinery end to end (Ray tasks, run folders, sweep.csv, the report by
# condition) in well under a minute; far too few steps for a policy to learn anything
DEMO_SWEEP_ARGS = ["--steps", "40", "--max-episode-steps", "10", "--learning-starts", "20", "--batch-size", "16",
                   "--buffer-size", "1000", "--net-arch", "32", "32", "--eval-every", "20", "--eval-goals", "1",
                   "--checkpoint-every", "40"]


def step_sweep(seed: int) -> dict:
    """`hingelab sweep`, a grid of 2 conditions (effort reward on and off) x 1 seed of a tiny
    `train low`, as Ray tasks on a local one-node Ray with this machine's cores."""

    shutil.rmtree(DEMO_SWEEP, ignore_errors=True)  # the demo's own output: remade each run
    try:
        import ray  # noqa: F401  (optional, in the test extra: the step runs only where it is installed)
    except ModuleNotFoundError:
        print('  Ray is not installed (pip install -c constraints.txt -e ".[test]"): step skipped')
        return {"skipped": True}
    DEMO_OUT.mkdir(parents=True, exist_ok=True)
    DEMO_SWEEP_FILE.write_text(
        "# hingelab demo: the effort-reward ablation at a toy budget (hingelab sweep)\n"
        "[sweep]\n"
        'command = "train low"\n'
        f"seeds = [{seed}]\n"
        f"args = {json.dumps(DEMO_SWEEP_ARGS)}\n"
        "cpus_per_trial = 1\n\n"
        "[conditions]\n"
        "effort = []\n"
        'no_effort = ["--no-effort"]\n')
    spec = load_sweep(DEMO_SWEEP_FILE)
    cpus = os.cpu_count() or 1
    started = time.perf_counter()
    records = run_sweep(spec, DEMO_SWEEP, num_cpus=cpus, progress=False)
    seconds = time.perf_counter() - started

    table = pd.read_csv(DEMO_SWEEP / SWEEP_CSV)  # what the sweep wrote, shown as a user would read it
    print(f"  {DEMO_SWEEP / SWEEP_CSV}:")
    shown = table[["trial", "condition", "seed", "state", "env_steps", "wall_time_s", "final_success_rate"]]
    print("    " + shown.to_string(index=False).replace("\n", "\n    "))
    print(f"  {summary(spec, DEMO_SWEEP, records, seconds, None)}")
    return {"sweep": str(DEMO_SWEEP), "sweep_csv": str(DEMO_SWEEP / SWEEP_CSV), "cpus": cpus,
            "trials": {row.trial: {"condition": row.condition, "seed": int(row.seed), "state": row.state,
                                   "env_steps": int(row.env_steps), "final_success_rate": float(row.final_success_rate)}
                       for row in table.itertuples()},
            "wall_time_s": seconds}


def step_report_and_recording(seed: int) -> dict:
    """a success-rate report and a Rerun recording of the demo dataset."""

    datasets = [DEMO_DATASET, DEMO_LOW_LEVEL_DATASET, DEMO_HIERARCHY_DATASET]
    datasets += [d for d in (DEMO_LEARNED_DATASET, DEMO_TRIAL_DATASET, DEMO_REAL_DATASET)
                 if (d / "dataset.json").exists()]
    runs = [DEMO_SWEEP] if (DEMO_SWEEP / "sweep.csv").exists() else []  # its trials, grouped by condition
    report = build_report(datasets, DEMO_OUT, runs=runs)
    result, _ = view(DEMO_DATASET, save=DEMO_OUT / "demo_heuristic.rrd", progress=False)
    # one line per dataset: the two tasks count different verdicts (the report names each)
    by_dataset = report.tables["success_by_dataset"]
    figures = "; ".join(f"{r.dataset} {r.successes}/{r.episodes} ({r.verdict})"
                        for r in by_dataset.itertuples())
    print(f"  report {report.html}: success {figures}; Rerun recording {result.saved_to} ({result.seconds:.1f} s)")
    if runs:
        final = report.tables["final_success"]
        print(f"  the sweep's learning curves by condition in the same report ({len(final)} conditions); success at "
              "the last evaluation: " + "; ".join(f"{r.run} {r.success_rate_mean:.2f} over {r.seeds} seed(s)"
                                                  for r in final.itertuples()))
    return {"report": str(report.html), "rrd": str(result.saved_to), "runs": [str(r) for r in runs],
            "by_dataset": {r.dataset: {"episodes": int(r.episodes), "successes": int(r.successes),
                                       "success_rate": float(r.success_rate), "verdict": r.verdict}
                           for r in by_dataset.itertuples()}}


STEPS = [
    ("robot platform (scene, hand, tweezer, arm)", step_platform),
    ("heuristic demos on ToolPick-v0 (privileged heuristic, perception on)", step_heuristic_demos),
    ("the shipped low-level policy on ToolShape-v0 (3 reachable latent goals)", step_low_level_policy),
    ("a scripted high level over the shipped low-level policy on ToolPick-v0 (the 2 cm sphere)",
     step_scripted_hierarchy),
    ("the shipped high-level policy over the shipped low-level policy on ToolPick-v0 (the 2 cm sphere)",
     step_learned_hierarchy),
    ("a trial on the MuJoCo stand-in of the rig, seen by its depth camera (hingelab trial)", step_stand_in_trial),
    ("a real-rig ROS 2 bag imported as episodes and exported back as ROS 2 bags", step_ros2_bags),
    ("a sweep of training runs on a local one-node Ray: effort reward on and off, a toy budget (hingelab sweep)",
     step_sweep),
    ("report and Rerun recording of the demo datasets", step_report_and_recording),
]
