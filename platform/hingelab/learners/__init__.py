"""Learners: one folder each, registered by name for the levels they train (``learners.registry``).

``sac``: SAC on ToolShape-v0 (``train low``), on ToolPick-v0 over the frozen low level with the
privileged prior (``train high``) and on ToolPickFlat-v0 (``train flat``); ``phase_clone``: the
phase clone of the scripted demonstrator (``train high --learner phase-clone``).
"""
