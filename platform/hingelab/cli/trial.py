"""``hingelab trial``: robot trials of the hierarchical policy, as a lab runs them on its rig."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from hingelab.analysis.pick_table import FAILURE_REASONS, pick_rates
from hingelab.episodes import create_dataset
from hingelab.errors import ConfigError
from hingelab.policies.high_level import SHIPPED_HIGH_LEVEL
from hingelab.robot import stand_in  # noqa: F401  (registers the "sim" robot)
from hingelab.robot.controller import CheckpointHighLevel, HierarchicalController, ScriptedStandInHighLevel
from hingelab.robot.interface import ROBOTS
from hingelab.robot.trial import TrialConfig, run_trials
from hingelab.seeds import STRIDE, TRIALS_BASE


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "trial", help="run trials of the hierarchical policy on a robot (the MuJoCo stand-in of the rig)",
        description="Run the hierarchical policy trial by trial as on the real rig: the depth camera's frames "
                    "through the camera cloud pipeline and the encoder, the high-level policy over the low-level "
                    "policy, up to 200 steps (10 s) and several attempts per trial. Each trial is one MCAP "
                    "episode in the dataset --out (source stand_in), with the depth images, the camera's "
                    "calibration and pose, the tool cloud, latents, joints, actions and the outcome. Without "
                    "--operator the simulation judges each trial (object within 1 cm of the target); with it you "
                    "are asked after each attempt. Writes trials.csv and a table with Wilson intervals "
                    "(table.csv); `hingelab report DIR` gives the paper's Fig. 7 layout.")
    p.add_argument("--robot", choices=tuple(ROBOTS), default="sim",
                   help="the robot (registered in hingelab.robot.interface): sim is the MuJoCo stand-in of the rig "
                        "(the default)")
    p.add_argument("--object", default="sphere",
                   help="object shape: sphere, cube, cylinder, tetrahedron or mesh:PATH (default sphere)")
    p.add_argument("--size", type=float, default=0.02, help="object size in m (default 0.02)")
    p.add_argument("--trials", type=int, default=12, help="trials (default 12, the paper's per shape)")
    p.add_argument("--out", type=Path, required=True, help="dataset folder to write (must be new or empty)")
    p.add_argument("--seed", type=int, default=0,
                   help=f"seed of the trials (default 0): trial k resets the stand-in with {TRIALS_BASE} + seed * "
                        f"{STRIDE} + k (hingelab.seeds)")
    p.add_argument("--policy", type=Path, default=None,
                   help="a high-level checkpoint (default: the shipped assets/checkpoints/high_level.zip; without "
                        "one, the stand-in runs the scripted high level and says so)")
    p.add_argument("--low-level", default=None,
                   help="the low-level policy: policy (the shipped one) or a checkpoint (default: the one the "
                        "high-level policy learned over)")
    p.add_argument("--operator", action="store_true",
                   help="ask the outcome of each attempt on the terminal: s(uccess), f(ailure) or a(bort)")
    p.add_argument("--depth-every", type=int, default=4,
                   help="record the depth image every N control steps (default 4: 5 Hz; 1 = every step, "
                        "~0.2 MB each)")
    p.add_argument("--max-steps", type=int, default=200, help="steps per trial (default 200, 10 s at 20 Hz)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _high_level(args, robot):

    path = args.policy or SHIPPED_HIGH_LEVEL
    if args.policy is None and not SHIPPED_HIGH_LEVEL.exists():
        print(f"hingelab trial: warning: no shipped high-level policy ({SHIPPED_HIGH_LEVEL}); the stand-in runs "
              "the scripted high level (the heuristic's motion over the low-level policy) instead", file=sys.stderr)
        return ScriptedStandInHighLevel(robot, args.low_level)
    return CheckpointHighLevel(path, args.low_level)


def run(args: argparse.Namespace) -> int:

    config = TrialConfig(object=args.object, size=args.size, trials=args.trials, seed=args.seed,
                         max_steps=args.max_steps, depth_every=args.depth_every, operator=args.operator)
    if args.out.exists() and any(args.out.iterdir()):
        raise ConfigError(f"{args.out} exists and is not empty; give a new folder to --out")
    robot = ROBOTS[args.robot](args.object, args.size, args.max_steps)  # a bad object: an error before files
    try:
        high = _high_level(args, robot)
        controller = HierarchicalController(high)
        card = {"robot": args.robot, "policy": high.label, "low_level": high.low_level, "object": args.object,
                "size": args.size, "trials": args.trials, "max_steps": args.max_steps, "operator": args.operator,
                "depth_every": args.depth_every, "seeds": f"{TRIALS_BASE} + seed * {STRIDE} + trial"}
        create_dataset(args.out, name=f"trial-{args.object}-{args.size * 100:g}cm", source=robot.source,
                       config=card, seed=args.seed,
                       description=f"hingelab trial on the {args.robot} robot: {high.label} over {high.low_level}, "
                                   f"{args.object} {args.size * 100:g} cm")
        try:
            rows = run_trials(robot, controller, args.out, config, progress=not args.no_progress,
                              extra_metadata={"policy": high.label, "low_level": high.low_level})
        except KeyboardInterrupt:
            partial = sorted((args.out / "episodes").glob("*.partial"))
            where = f" ({partial[-1]})" if partial else ""
            print(f"hingelab trial: interrupted; the trial under way is kept as a .partial file{where}: salvage it "
                  f"with `hingelab datasets recover FILE --out NEWFILE`; the finished trials are in {args.out}",
                  file=sys.stderr)
            raise
    finally:
        robot.close()
    rows.to_csv(args.out / "trials.csv", index=False)
    row = {"object": args.object, "size_cm": 100 * args.size, "trials": len(rows), **pick_rates(rows)}

    pd.DataFrame([row]).to_csv(args.out / "table.csv", index=False)
    failures = ", ".join(f"{r} {row[f'failures_{r}']}" for r in FAILURE_REASONS if row[f"failures_{r}"])
    other = rows.loc[~rows["success"] & ~rows["failure_reason"].isin(FAILURE_REASONS), "failure_reason"]
    if len(other):
        failures = ", ".join(filter(None, [failures, *(f"{k} {v}" for k, v in other.value_counts().items())]))
    judged = "the operator" if args.operator else "the simulation (object within 1 cm of the target)"
    print(f"{len(rows)} trials of {high.label} over {high.low_level} on the {args.robot} robot, {args.object} "
          f"{args.size * 100:g} cm, judged by {judged}: first attempt {int(row['first_attempt_successes'])}/"
          f"{len(rows)} = {row['first_attempt_success_rate']:.2f} [{row['first_attempt_ci_low']:.2f}, "
          f"{row['first_attempt_ci_high']:.2f}], with further attempts {int(row['successes'])}/{len(rows)} = "
          f"{row['success_rate']:.2f} [{row['ci_low']:.2f}, {row['ci_high']:.2f}]; failures: {failures or 'none'}. "
          f"Dataset, trials.csv, table.csv in {args.out}.")
    return 0
