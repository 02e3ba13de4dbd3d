"""Beyond one machine: hingelab's runs on Ray.

* ``ray_runtime``: joining a Ray cluster (``--address``) or starting a local one-node Ray, quietly
  (no usage reports, no dashboard), and always leaving it again.
* ``local_ray_reaper``: a local Ray dies with its driver, even a SIGKILLed one (a reaper process
  stops the processes of the driver's Ray session).
* ``fan_out``: rollout episodes as Ray tasks (``--ray`` on ``generate heuristic``, ``eval low``,
  ``eval high``): each task writes its MCAP episode straight into the dataset folder and returns a
  small summary.
* ``sweep_file``: the ``SWEEP.toml`` format of ``hingelab sweep``, checked against the training
  command's own parser before anything starts.
* ``trial_task``: one trial, the training command in a child process of a Ray task.
* ``sweep``: a grid of training runs, one Ray task per trial, ``DIR/sweep.csv``, resume.

Storage: every node must see the dataset and sweep folders at the same path (NFS or another
shared file system): tasks write there, only summaries travel through Ray.
"""
