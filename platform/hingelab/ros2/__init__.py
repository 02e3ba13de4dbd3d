"""Real-robot logs in and out: ROS 2 bags recorded on the rig <-> hingelab episodes.

- ``topics.py``: the topics an import reads (kinds, default names, message types, ``--topic``);
- ``bag_source.py``: opening a bag (rosbag2 folder with MCAP or sqlite3 storage, a standalone
  ``.mcap``, or an MCAP bag cut off mid-chunk) and reading its streams, with what was dropped;
- ``ros_messages.py``: ROS messages <-> numpy (PointCloud2, depth images, camera info, poses);
- ``tf_tree.py``: the camera's pose in ``hand_base`` from ``/tf`` and ``/tf_static`` at a time;
- ``trials.py``: ``/trial/event`` -> trials (start..end) and their outcomes;
- ``bag_import.py``: a bag -> episodes (20 Hz steps, latest-at-or-before sampling, ages);
- ``object_from_cloud.py``: the object's position and extent from the camera frames of a bag without an
  object pose (``--object-from-cloud``), through the stand-in's object estimators;
- ``bag_export.py``: episodes -> rosbag2 folders with MCAP storage.

Everything goes through ``rosbags`` (pure Python, no ROS install): it reads and writes
rosbag2 folders of either storage and standalone MCAP bags, and builds its message types from
the definitions stored in the bag, so a rig's own message versions decode as recorded.
"""
