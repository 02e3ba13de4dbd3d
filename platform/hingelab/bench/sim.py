"""``hingelab bench sim``: control steps per second of the sim core vs raw ``mj_step``.

The baseline is the physics alone: the same model stepped by ``mj_step`` in a bare loop,
converted to control steps (``n_substeps`` physics steps each). Ours is ``SimCore.step``
with the full control path (relative hand targets, for tool_pick also the Jacobian arm
velocity), plus the privileged-state read it returns. The raw loop replays the servo
targets our run produced, so both integrate the same motion from the ``grasp``
keyframe; runs are interleaved in one process and the best of each is kept.
"""

from __future__ import annotations

import time

import mujoco
import numpy as np

from hingelab.bench.table import BenchTable
from hingelab.sim.core import SimCore

# the code and models this benchmark measures (the bench module itself: hingelab.bench.measured_paths)
MEASURES = ("platform/hingelab/sim", "assets/scenes", "assets/svh_hand", "assets/tweezer", "assets/jaka_zu7",
            "assets/objects")


def _core_rate(sim: SimCore, control_steps: int, rng: np.random.Generator) -> tuple[float, np.ndarray]:
    """SimCore.step with random small hand actions (and arm velocities); returns the rate and
    the servo targets it produced, for the raw loop to replay."""
    sim.reset(seed=0)
    hand = rng.uniform(-0.01, 0.01, size=(control_steps, 9))
    arm = rng.uniform(-0.02, 0.02, size=(control_steps, 3)) if sim.has_arm else [None] * control_steps
    ctrls = np.zeros((control_steps, sim.model.nu))
    start = time.perf_counter()
    for k in range(control_steps):
        sim.step(hand_action=hand[k], arm_velocity=arm[k])
        ctrls[k] = sim.data.ctrl
    return control_steps / (time.perf_counter() - start), ctrls


def _raw_rate(model: mujoco.MjModel, ctrls: np.ndarray, n_substeps: int) -> float:
    """The same servo targets through a bare mj_step loop: the same physics, no controller."""
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("grasp").id)
    start = time.perf_counter()
    for ctrl in ctrls:
        data.ctrl[:] = ctrl
        for _ in range(n_substeps):
            mujoco.mj_step(model, data)
    return len(ctrls) / (time.perf_counter() - start)


def run(quick: bool = False) -> BenchTable:
    control_steps = 100 if quick else 1000
    repeats = 1 if quick else 5
    rows = []
    ratios = {}
    rng = np.random.default_rng(0)
    for scene in ("tool_shape", "tool_pick"):
        sim = SimCore(scene)
        raw, ours = [], []
        for _ in range(repeats):  # interleaved, best of each: the machine is shared
            rate, ctrls = _core_rate(sim, control_steps, rng)
            ours.append(rate)
            raw.append(_raw_rate(sim.model, ctrls, sim.n_substeps))
        raw_best, ours_best = max(raw), max(ours)
        rows.append({
            "scene": scene,
            "physics steps per control step": sim.n_substeps,
            "raw mj_step (control steps/s)": raw_best,
            "SimCore.step (control steps/s)": ours_best,
            "ratio ours/raw": ours_best / raw_best,
            "real-time factor (ours)": ours_best * sim.control_dt,
        })
        ratios[f"{scene}: SimCore / raw mj_step"] = ours_best / raw_best
    return BenchTable(
        name="sim",
        title="Sim core speed: control steps per second vs raw mj_step on the same model",
        columns=list(rows[0].keys()),
        rows=rows,
        ratios=ratios,
        notes=[f"{control_steps} control steps (20 Hz, 0.002 s physics), best of {repeats} interleaved runs, one core.",
               "Raw = a bare mj_step loop replaying the servo targets of our run (same motion), in control steps; "
               "ours adds relative hand targets, the arm's Jacobian controller (tool_pick), a kinematics "
               "refresh, divergence checks and the privileged read."],
        config={"control_steps": control_steps, "repeats": repeats},
    )
