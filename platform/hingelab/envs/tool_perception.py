"""The tool as the policies see it: a synthesized cloud per step through ``ToolState``.

One object per env: the cloud synthesizer (realism on, its per-episode pose error drawn
at reset) and the tool-state tracker (registration, differencing, encoder, EMA).
"""

from __future__ import annotations

import numpy as np

from hingelab.perception.clouds import IDEAL, CloudRealism, CloudSynthesizer
from hingelab.perception.encoder import ToolEncoder, load_encoder
from hingelab.perception.tool_state import ALPHA, ToolState, ToolStateSample
from hingelab.sim.core import SimCore


class ToolPerception:
    """``reset(seed)`` then ``observe(sim) -> ToolStateSample`` (B = 1) once per control step."""

    def __init__(self, encoder: ToolEncoder | None = None, realistic: bool = True, dt: float = 0.05,
                 alpha: float = ALPHA):
        self.encoder = encoder or load_encoder()
        self.synthesizer = CloudSynthesizer(realism=CloudRealism() if realistic else IDEAL)
        self.tool_state = ToolState(encoder=self.encoder, n_tools=1, dt=dt, alpha=alpha)
        self.cloud: np.ndarray | None = None  # (256, 3) float32, hand_base: the last cloud

    def reset(self, seed: int | None) -> None:
        self.synthesizer.new_episode(seed)
        self.tool_state.reset()

    def observe(self, sim: SimCore) -> ToolStateSample:
        self.cloud = self.synthesizer.from_sim(sim.model, sim.data)
        return self.tool_state.update(self.cloud[None], n_distinct=self.synthesizer.n_distinct)

    @property
    def calibration(self):
        return self.encoder.calibration
