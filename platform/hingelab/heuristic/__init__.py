"""The privileged heuristic controller that fills the high-level replay buffer (paper)."""
