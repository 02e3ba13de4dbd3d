"""Episode metadata: MCAP metadata values are strings; this is how they are written and parsed.

Formats (documented in ``datasets/README.md``):

- integers (``seed``, ``length``, ``attempt``, ``schema_version``, ``log_time_origin_ns``): decimal, ``"42"``
- floats (``return``, ``start_time_s``, ``end_time_s``): Python ``repr``, the shortest
  string that round-trips the float64 exactly (``"12.75"``, ``"nan"``, ``"inf"``)
- booleans (``success``, ``recovered``, ``last_step_success``, ``first_attempt_success``): ``"true"`` / ``"false"``
- lists of names (``joint_names``): comma-separated, no spaces
- everything else: the string itself. A fact that is unknown is left out, never ``"None"``.
"""

from __future__ import annotations

import json
import math
import zlib
from collections.abc import Mapping

import numpy as np

from hingelab.episodes import schemas as S
from hingelab.episodes.schemas import DIGEST_COLUMNS

INT_KEYS = frozenset({S.KEY_SEED, S.KEY_LENGTH, S.KEY_ATTEMPT, S.KEY_SCHEMA_VERSION, S.KEY_LOG_TIME_ORIGIN})
FLOAT_KEYS = frozenset({S.KEY_RETURN, S.KEY_START_TIME, S.KEY_END_TIME})
BOOL_KEYS = frozenset({S.KEY_SUCCESS, S.KEY_TRUNCATED_FILE, S.KEY_LAST_STEP_SUCCESS, S.KEY_FIRST_ATTEMPT_SUCCESS})
LIST_KEYS = frozenset({S.KEY_JOINT_NAMES})


def format_value(value) -> str:
    """One metadata value as the string stored in the file (see module docstring)."""
    if isinstance(value, str):
        return value
    if isinstance(value, bool) or type(value).__name__ == "bool_":
        return "true" if value else "false"
    if isinstance(value, int) or type(value).__name__.startswith(("int", "uint")):
        return str(int(value))
    if isinstance(value, float) or type(value).__name__.startswith("float"):
        return repr(float(value))
    if isinstance(value, (list, tuple)):
        return ",".join(str(v) for v in value)
    return str(value)


def format_metadata(values: Mapping) -> dict[str, str]:
    """Format a dict of facts for ``add_metadata``; ``None`` values are left out."""
    return {str(k): format_value(v) for k, v in values.items() if v is not None}


def metadata_digest(record: Mapping[str, str]) -> int:
    """CRC32 of a metadata record's keys and values (as stored), independent of their order."""
    return zlib.crc32(json.dumps(dict(record), sort_keys=True).encode())


def digest_columns(records: Mapping[str, Mapping[str, str]]) -> dict:
    """The ``/episode/columns`` entries protecting ``records`` (name -> stored record) by CRC."""
    return {f"{DIGEST_COLUMNS}:{name}": np.array([metadata_digest(record)], dtype=np.uint32)
            for name, record in records.items()}


def parse_value(key: str, text: str):
    """Parse one stored value back into int / float / bool / list / str by its key."""
    if key in INT_KEYS:
        return int(text)
    if key in FLOAT_KEYS:
        return float(text)
    if key in BOOL_KEYS:
        if text not in ("true", "false"):
            raise ValueError(f"metadata {key}={text!r} is not 'true' or 'false'")
        return text == "true"
    if key in LIST_KEYS:
        return text.split(",") if text else []
    return text


def parse_metadata(values: Mapping[str, str]) -> dict:
    """Parse a whole ``episode`` record into Python values."""
    return {k: parse_value(k, v) for k, v in values.items()}


def is_nan(value) -> bool:
    return isinstance(value, float) and math.isnan(value)
