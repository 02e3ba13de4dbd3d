"""Errors about datasets and episode files that a user can fix (printed as one line)."""

from __future__ import annotations

from hingelab.errors import HingelabError


class DatasetError(HingelabError):
    """A dataset folder or an episode file is missing, cut off, corrupt or foreign.

    The message names the file and what to do about it.
    """
