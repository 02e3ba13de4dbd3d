"""``hingelab trial``: robot trials of the hierarchical policy, as a lab runs them on its rig
(``hingelab.robot.trial.run_trial_session`` does the work; this module parses and prints)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hingelab.arguments import finite_float
from hingelab.cli.names import HAND_EYE, ROBOTS, TOOL_POSITIONS
from hingelab.cli.options import add_max_mesh_mb, add_object_perception
from hingelab.folder_lock import folder_lock
from hingelab.out_dir import DATASET, check_out
from hingelab.seeds import STRIDE, TRIALS_BASE, seed_argument


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
    p.add_argument("--robot", default="sim",
                   help=f"the robot (registered in hingelab.robot.interface: {', '.join(ROBOTS)}, or a plug-in's): "
                        "sim is the MuJoCo stand-in of the rig (the default)")
    p.add_argument("--object", default="sphere",
                   help="object: sphere, cube, cylinder, tetrahedron, mesh:PATH or family:NAME[:SEED] (a new "
                        "object each trial from a procedural family: hingelab.sim.object_families) (default sphere)")
    add_max_mesh_mb(p)
    p.add_argument("--size", type=finite_float, default=0.02,
                   help="object size in m; a family's size cap, 0.008 to 0.03 (default 0.02)")
    p.add_argument("--trials", type=int, default=12, help="trials (default 12, the paper's per shape)")
    p.add_argument("--out", type=Path, required=True, help="dataset folder to write (must be new or empty)")
    p.add_argument("--seed", type=seed_argument, default=0,
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
    add_object_perception(p, " (the stand-in, --robot sim: a real rig's estimate is its own)")
    p.add_argument("--tool-position", choices=TOOL_POSITIONS, default=None,
                   help="the tool position the high level observes: observed (the tracked one; it carries the "
                        "camera's hand-eye error), anchored (the nominal in-hand position plus the tracked change "
                        "since the trial's first frame), relative (the whole pose's change since the first frame "
                        "on the nominal pose) or nominal (the nominal in-hand pose, no tracking); default: what the "
                        "policy was trained on")
    p.add_argument("--hand-eye", choices=HAND_EYE, default=HAND_EYE[0],
                   help="the depth camera's pose: calibrated (the default: as calibrated, with its error of up to "
                        "3 mm and 1 degree per axis) or refined (corrected at each trial's first frame by aligning "
                        "the arm's and hand's points in the depth image with their model: "
                        "hingelab.perception.hand_eye; the fit is in each episode's record) or exact (the camera's "
                        "true pose: a diagnostic of what the calibration error costs) (the stand-in)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hingelab.robot.trial import TrialConfig, run_trial_session  # on run: the parser stays light (hingelab.cli)

    check_out(args.out, DATASET)
    config = TrialConfig(object=args.object, size=args.size, trials=args.trials, seed=args.seed,
                         max_steps=args.max_steps, depth_every=args.depth_every, operator=args.operator,
                         object_perception=args.object_perception, tool_position=args.tool_position,
                         hand_eye=args.hand_eye)
    with folder_lock(args.out, args.argv):
        session = run_trial_session(args.robot, config, args.out, policy=args.policy, low_level=args.low_level,
                                    progress=not args.no_progress, warn=lambda text: print(text, file=sys.stderr))
    print(session.summary)
    return 0
