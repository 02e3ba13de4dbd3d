"""Robots behind one interface: the MuJoCo stand-in of the rig, and the place a real driver plugs in.

``interface``: what the hierarchical controller reads and commands (``Robot``, ``RobotReadings``);
``stand_in``: the MuJoCo stand-in (``StandInRobot``); ``controller``: the hierarchical policy acting
on readings (``HierarchicalController``); ``trial``: ``hingelab trial``'s loop and recording;
``arm_kinematics``: the hand's pose in the world from the arm's joint angles (MuJoCo's kinematics of
the Zu 7), for logs of a real arm that record joints only.
"""
