"""The seed plan: every stream of episode seeds the platform draws from, in one place.

(Being completed: the streams still defined beside their commands move here.)
"""

from __future__ import annotations

HELD_OUT_BASE = 2_000_000_000  # low-level held-out goals' episode seeds, above every training episode's
MEMBER_STRIDE = 1_000_003


def ensemble_member_seed(seed: int, member: int) -> int:
    """The fit seed of member ``member`` of an ensemble fitted with ``seed`` (member 0: ``seed`` itself)."""
    return int(seed) + int(member) * MEMBER_STRIDE


__all__ = ["HELD_OUT_BASE", "MEMBER_STRIDE", "ensemble_member_seed"]
