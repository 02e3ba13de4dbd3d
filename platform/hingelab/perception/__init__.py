"""Tool perception: tool point clouds -> pose, velocities and the shape latent z.

One concern per module (data flows down the list):

- ``clouds``: synthesize 256-point tool clouds from the simulator's part poses.
- ``registration``: register a cloud to the canonical cloud (pose t, R, Euler angles);
  ``registration_kernels`` its compiled iterations, ``pose_kernels`` the per-step pose arithmetic.
- ``encoder``: the PointNet VAE (cloud in the canonical frame -> 2-D latent z).
- ``train_encoder``: train it from a synthetic cloud dataset; checkpoints.
- ``calibration``: latent z <-> opening (rad, tip gap in mm).
- ``tool_state``: ``ToolState``, the stream of clouds -> the policies' tool state.
- ``synthetic_dataset``: the ``synthetic_clouds`` episode dataset for the encoder.
"""
