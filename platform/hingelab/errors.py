"""Errors a user can fix: the CLI prints them as one line, without a traceback.

Messages name the thing that is wrong (a file, an object name, a value) and
what to do about it.
"""


class HingelabError(Exception):
    """Base class of every user-facing error."""


class AssetError(HingelabError):
    """A model file is missing or malformed, or a requested asset is unknown."""


class ConfigError(HingelabError, ValueError):
    """A value given by the user is out of range or of the wrong kind."""


class DiskFullError(HingelabError):
    """The disk filled up during a run; what was finished is kept and the run can be resumed."""


class FolderBusyError(HingelabError):
    """Another hingelab command is writing the folder (``hingelab.folder_lock``); one writer per folder."""
