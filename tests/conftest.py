"""Shared fixtures: scenes are compiled once per session (each compile takes ~50 ms)."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture(scope="session")
def synergy():
    from hingelab.sim.finger_synergy import FingerSynergy

    return FingerSynergy.load()
