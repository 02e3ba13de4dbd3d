"""JSON that every reader can parse: ``strict_dumps`` refuses NaN and infinity (``json.dumps`` writes them as
``NaN``/``Infinity``, which is not JSON) with one line naming the file and the field."""

from __future__ import annotations

import json
import math

from hingelab.errors import ConfigError


def _non_finite(value, path: str = "") -> str | None:
    """The dotted path of the first NaN or infinity in ``value`` (None: there is none)."""
    if isinstance(value, float) and not math.isfinite(value):
        return path or "(the value)"
    if isinstance(value, dict):
        items = value.items()
    elif isinstance(value, (list, tuple)):
        items = enumerate(value)
    else:
        return None
    for key, item in items:
        found = _non_finite(item, f"{path}.{key}" if path else str(key))
        if found:
            return found
    return None


def finite_or_null(value):
    """``value`` with every NaN and infinity (at any depth of dicts, lists and tuples) as None: JSON's null, for
    records where a missing number is a fact (a journal row, a comparison that could not be made)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: finite_or_null(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_null(v) for v in value]
    return value


def strict_dumps(doc, where, **kwargs) -> str:
    """``json.dumps(doc, allow_nan=False, **kwargs)``; a NaN or infinity is a ``ConfigError`` naming ``where``
    (the file the text goes to) and the field that holds it."""
    try:
        return json.dumps(doc, allow_nan=False, **kwargs)
    except ValueError as exc:
        field = _non_finite(json.loads(json.dumps(doc, **kwargs)))
        if field is None:
            raise
        raise ConfigError(f"{where}: {field} is not a finite number, and JSON has none; nothing was written "
                          "(give finite values)") from exc


def metadata_dumps(metadata: dict) -> str:
    """An episode's metadata as export text (a ROS 2 String, a LeRobot or Minari attribute): NaN and infinity as
    null (an episode written before JSON was strict may hold them), other objects as their ``str``."""
    return json.dumps(finite_or_null(metadata), default=str, sort_keys=True, allow_nan=False)


__all__ = ["finite_or_null", "metadata_dumps", "strict_dumps"]
