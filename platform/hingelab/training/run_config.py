"""Run configs: frozen dataclasses whose fields are the command line of a learner.

Each field is declared with ``option(default, help, ...)``; ``add_config_arguments`` turns
every field into a flag (``--field-name`` unless the field names another) with the field's
help and default, and ``config_from_args`` builds the config back from the parsed flags.
So a hyperparameter added to a config is reachable from ``hingelab train ...`` at once,
and ``--help`` lists them all. ``RunConfig`` adds the JSON round trip of ``RUNDIR/config.json``.

Flag kinds follow the default's type: bool (``--x``/``--no-x``; a ``negate=True`` field has its own
negating flag, e.g. ``--no-effort``, and ``--field-name`` for True), int, float, str, tuple
(``nargs="+"`` of ``item``), dict (a JSON object), and ``None`` defaults with an explicit ``parse``.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import MISSING, asdict, field, fields
from pathlib import Path
from typing import Any, Callable

from hingelab.arguments import add_oversubscribe, finite_float
from hingelab.errors import ConfigError


def option(default: Any = MISSING, help: str = "", *, flag: str | None = None, negate: bool = False,
           choices: tuple | None = None, metavar: str | None = None, parse: Callable | None = None,
           item: Callable | None = None, cli: bool = True, default_factory: Any = MISSING):
    """A config field that is also a flag. ``flag``: the flag's name (default ``--`` + the field
    name with dashes); ``negate``: a bool field set False by its flag (``--no-effort``);
    ``parse``: argparse ``type``; ``item``: the type of a tuple's items; ``cli=False``: a field
    the command line does not set (the command sets it itself)."""
    metadata = {"help": help, "flag": flag, "negate": negate, "choices": choices, "metavar": metavar,
                "parse": parse, "item": item, "cli": cli}
    if default_factory is not MISSING:
        return field(default_factory=default_factory, metadata=metadata)
    return field(default=default, metadata=metadata)


def flag_of(f) -> str:
    return f.metadata.get("flag") or "--" + f.name.replace("_", "-")


def _default_text(value: Any) -> str:
    if value is None or value == "":
        return "none"
    if isinstance(value, tuple):
        return " ".join(str(v) for v in value) or "none"
    if isinstance(value, dict):
        return json.dumps(value)
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def _json_object(text: str) -> dict:
    try:
        value = json.loads(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{text!r} is not JSON ({exc})") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"{text!r} is not a JSON object")
    return value


def _declared_default(f):
    return f.default_factory() if f.default is MISSING and f.default_factory is not MISSING else f.default


def add_config_arguments(parser: argparse.ArgumentParser, config_class, skip: tuple = (),
                         title: str | None = None) -> None:
    """One flag per field of ``config_class`` (those with ``cli=True``, not in ``skip``), with its declared default:
    the config is not built, so a ``--help`` runs none of its checks (a residual's reads its base checkpoint, torch
    and all: seconds)."""
    group = parser.add_argument_group(title) if title else parser
    for f in fields(config_class):
        meta = f.metadata
        if not meta.get("cli", True) or f.name in skip:
            continue
        default = _declared_default(f)
        help_text = meta.get("help", "")
        kwargs: dict[str, Any] = {"dest": f.name}
        if isinstance(default, bool):
            if meta.get("negate"):  # its flag sets False (--no-effort); --field-name sets True
                group.add_argument(flag_of(f), action="store_false", default=argparse.SUPPRESS,
                                   help=f"{help_text}{' (the default)' if not default else ''}", **kwargs)
                group.add_argument("--" + f.name.replace("_", "-"), action="store_true", default=argparse.SUPPRESS,
                                   help=f"the opposite{' (the default)' if default else ''}", **kwargs)
            else:
                group.add_argument(flag_of(f), action=argparse.BooleanOptionalAction, default=argparse.SUPPRESS,
                                   help=f"{help_text} (default {_default_text(default)})", **kwargs)
            continue
        kwargs["default"] = argparse.SUPPRESS  # absent unless given: a --resume tells given flags from defaults
        if meta.get("metavar"):
            kwargs["metavar"] = meta["metavar"]
        if meta.get("choices"):
            kwargs["choices"] = meta["choices"]
        if isinstance(default, tuple) and meta.get("parse") is None:
            kwargs.update(nargs="*" if not default else "+", type=meta.get("item") or str)
        elif isinstance(default, dict):
            kwargs["type"] = _json_object
        else:
            kwargs["type"] = meta.get("parse") or (finite_float if isinstance(default, float) else type(default))
        group.add_argument(flag_of(f), help=f"{help_text} (default {_default_text(default)})", **kwargs)


def add_run_arguments(p, default_out: str) -> None:
    """The flags every learner's command has besides its config's."""
    p.add_argument("--out", type=Path, default=None,
                   help=f"run folder (default {default_out}); never under assets/ without --force")
    p.add_argument("--force", action="store_true", help="allow a run folder that replaces files under assets/")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in --out from its last checkpoint (its saved config is kept; "
                        "--steps may raise the budget)")
    p.add_argument("--name", default=None, help="curve label in reports (default: the run folder's name)")
    add_oversubscribe(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def given_settings(config_class, args: argparse.Namespace) -> set[str]:
    """The config fields whose flags were given on the command line (``add_config_arguments`` leaves
    the others out of ``args``)."""
    return {f.name for f in fields(config_class) if hasattr(args, f.name)}


def config_from_args(config_class, args: argparse.Namespace, **overrides):
    """The config of the parsed flags (fields whose flags were not given keep their defaults unless
    overridden)."""
    defaults = config_class()
    values = {f.name: getattr(args, f.name) for f in fields(config_class) if hasattr(args, f.name)}
    for name, value in values.items():
        if isinstance(getattr(defaults, name), tuple) and isinstance(value, list):
            values[name] = tuple(value)
    values.update(overrides)
    return config_class(**values)


class RunConfig:
    """JSON round trip of a frozen dataclass config (``to_dict``, ``from_dict``, ``load``)."""

    kind = "run"  # in error messages: "unknown low-level config keys"
    legacy_keys: frozenset = frozenset()  # keys an older hingelab wrote into this config that it now ignores
    # (in any config part) keys an older hingelab did not write, and the value its runs had: from_dict uses it
    defaults_before: dict = {}

    def to_dict(self) -> dict:
        out = asdict(self)
        for key, value in out.items():
            if isinstance(value, tuple):
                out[key] = [str(v) if isinstance(v, Path) else v for v in value]
        return out

    @classmethod
    def from_dict(cls, data: dict):
        known = {f.name: f for f in fields(cls)}
        data = {k: v for k, v in data.items() if k in known or k not in cls.legacy_keys}
        for part in cls.__mro__:  # a key a saved config lacks: what runs did before the key existed
            for key, value in vars(part).get("defaults_before", {}).items():
                if key in known:
                    data.setdefault(key, value)
        unknown = sorted(set(data) - set(known))
        if unknown:
            raise ConfigError(f"unknown {cls.kind} config keys {unknown}; "
                              "this run was made by another hingelab version")
        defaults = cls()
        values = {}
        for key, value in data.items():
            if isinstance(getattr(defaults, key), tuple) and isinstance(value, list):
                value = tuple(value)
            elif known[key].metadata.get("parse") is not None and isinstance(value, list):
                value = tuple(value)  # a tuple-or-None field (e.g. --goal-openings)
            values[key] = value
        return cls(**values)

    @classmethod
    def load(cls, path: Path):
        try:
            data = json.loads(Path(path).read_text())
        except (OSError, ValueError) as exc:
            raise ConfigError(f"cannot read the run config {path}: {exc}") from exc
        return cls.from_dict(data.get("config", data))

    def check(self, checks: dict[str, bool]) -> None:
        """Raise one ConfigError naming every field whose check failed."""
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise ConfigError(f"invalid {self.kind} training config: "
                              f"{', '.join(f'{b}={getattr(self, b)!r}' for b in bad)}")


__all__ = ["option", "add_config_arguments", "add_run_arguments", "config_from_args", "given_settings", "flag_of",
           "RunConfig"]
