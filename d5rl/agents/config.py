"""A small typed, frozen config: one source of defaults per agent.

Each agent's ``get_config()`` returns a :class:`Config`; the CLI applies
``--set key=value`` overrides with :meth:`Config.override`, which parses each
value as the type of its default (``hidden_dims=512,512`` → ``(512, 512)``).
Configs are immutable and hashable, so they can live in a jitted agent as a
static field.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterable, Iterator, Mapping
from typing import Any

from d5rl.errors import D5RLError


class ConfigError(D5RLError, KeyError):
    """An unknown config key or a value that does not parse as its default's type."""


def _freeze(value: Any) -> Any:
    if isinstance(value, list):
        return tuple(_freeze(v) for v in value)
    if isinstance(value, tuple):
        return tuple(_freeze(v) for v in value)
    if isinstance(value, dict):
        return Config(value)
    return value


def _parse(text: str, default: Any, key: str) -> Any:
    """Parse ``text`` as the type of ``default``."""
    t = text.strip()
    try:
        if t.lower() in ("none", "null") and (default is None or not isinstance(default, str)):
            return None
        if isinstance(default, bool):
            if t.lower() in ("1", "true", "yes", "on"):
                return True
            if t.lower() in ("0", "false", "no", "off"):
                return False
            raise ValueError(t)
        if isinstance(default, int):
            return int(t)
        if isinstance(default, float):
            return float(t)
        if isinstance(default, tuple):
            parts = [p for p in t.strip("()[]").split(",") if p.strip()]
            proto = default[0] if default else 0
            return tuple(_parse(p, proto, key) for p in parts)
        if isinstance(default, str):
            return t
        if default is None:  # untyped: try JSON, fall back to the string
            try:
                return _freeze(json.loads(t))
            except json.JSONDecodeError:
                return t
    except ValueError:
        pass
    raise ConfigError(
        f"config value {key}={text!r} does not parse as {type(default).__name__} (default {default!r})",
        f"give {key} a value like {default!r}",
    )


class Config(Mapping):
    """An immutable mapping with attribute access (``config.batch_size``)."""

    __slots__ = ("_data", "_hash")

    def __init__(self, data: Mapping[str, Any] | None = None, **kwargs: Any):
        d = dict(data or {})
        d.update(kwargs)
        object.__setattr__(self, "_data", {k: _freeze(v) for k, v in d.items()})
        object.__setattr__(self, "_hash", None)

    def __getattr__(self, name: str) -> Any:
        data = object.__getattribute__(self, "_data")
        try:
            return data[name]
        except KeyError:
            raise AttributeError(f"config has no key {name!r}; keys: {sorted(data)}") from None

    def __setattr__(self, name, value):
        raise AttributeError("Config is immutable; use .replace(...)")

    def __getitem__(self, key: str) -> Any:
        return self._data[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._data)

    def __len__(self) -> int:
        return len(self._data)

    def __hash__(self) -> int:
        if self._hash is None:
            object.__setattr__(self, "_hash", hash(tuple(sorted(self._data.items()))))
        return self._hash

    def __eq__(self, other) -> bool:
        return isinstance(other, Config) and self._data == other._data

    def __repr__(self) -> str:
        return f"Config({self._data!r})"

    def replace(self, **kwargs: Any) -> Config:
        """A copy with some keys changed; unknown keys raise :class:`ConfigError`."""
        unknown = [k for k in kwargs if k not in self._data]
        if unknown:
            raise ConfigError(f"unknown config keys {unknown}", f"known keys: {sorted(self._data)}")
        return Config({**self._data, **kwargs})

    def override(self, assignments: Iterable[str] | Mapping[str, Any] | None) -> Config:
        """Apply ``["key=value", ...]`` (strings parsed by type) or a mapping of values."""
        if not assignments:
            return self
        if isinstance(assignments, Mapping):  # text values are parsed like "key=value" strings
            assignments = [f"{k}={v}" for k, v in assignments.items() if isinstance(v, str)] + [
                (k, v) for k, v in assignments.items() if not isinstance(v, str)
            ]
            return self._apply(assignments)
        return self._apply(assignments)

    def _apply(self, assignments) -> Config:
        updates = {}
        for item in assignments:
            if isinstance(item, tuple):  # (key, value) already typed
                key, value = item
                if key not in self._data:
                    raise ConfigError(f"unknown config key {key!r}", f"known keys: {sorted(self._data)}")
                updates[key] = value
                continue
            if "=" not in item:
                raise ConfigError(f"override {item!r} is not key=value", "write e.g. --set batch_size=128")
            key, text = item.split("=", 1)
            key = key.strip()
            if key not in self._data:
                raise ConfigError(f"unknown config key {key!r}", f"known keys: {sorted(self._data)}")
            updates[key] = _parse(text, self._data[key], key)
        return self.replace(**updates)

    def to_dict(self) -> dict[str, Any]:
        def plain(v):
            if isinstance(v, Config):
                return v.to_dict()
            if isinstance(v, tuple):
                return [plain(x) for x in v]
            return v

        return {k: plain(v) for k, v in self._data.items()}


# --- value checks -------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Bound:
    """What a numeric config value may be: its type, bounds, and whether None is allowed."""

    kind: type  # int or float (an int is accepted where a float is expected)
    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    optional: bool = False  # None is allowed (means "automatic")
    each: bool = False  # a tuple of such values (e.g. hidden layer widths), at least one

    def describe(self) -> str:
        bounds = " and ".join(
            f"{op} {v:g}"
            for op, v in ((">=", self.ge), (">", self.gt), ("<=", self.le), ("<", self.lt))
            if v is not None
        )
        text = ("an integer" if self.kind is int else "a number") + (f" {bounds}" if bounds else "")
        text = (
            f"a list of {text.replace('an integer', 'integers').replace('a number', 'numbers')}" if self.each else text
        )
        return text + (" or none" if self.optional else "")

    def accepts(self, v: Any) -> bool:
        if v is None:
            return self.optional
        if self.each:
            return (
                isinstance(v, tuple) and len(v) > 0 and all(dataclasses.replace(self, each=False).accepts(x) for x in v)
            )
        if isinstance(v, bool) or not isinstance(v, (int, float)) or (self.kind is int and not isinstance(v, int)):
            return False
        if not math.isfinite(v):
            return False
        return (
            (self.ge is None or v >= self.ge)
            and (self.gt is None or v > self.gt)
            and (self.le is None or v <= self.le)
            and (self.lt is None or v < self.lt)
        )


# Keys that mean the same in every agent's config, checked wherever they appear.
AGENT_BOUNDS = {
    "batch_size": Bound(int, ge=1),
    "actor_lr": Bound(float, gt=0),
    "critic_lr": Bound(float, gt=0),
    "value_lr": Bound(float, gt=0),
    "temp_lr": Bound(float, gt=0),
    "hidden_dims": Bound(int, ge=1, each=True),
    "critic_hidden_dims": Bound(int, ge=1, each=True),
    "discount": Bound(float, gt=0, le=1),
    "tau": Bound(float, ge=0, le=1),
    "num_qs": Bound(int, ge=1),
    "num_min_qs": Bound(int, ge=1),
    "utd_ratio": Bound(int, ge=1),
    "expectile": Bound(float, gt=0, lt=1),
    "offline_ratio": Bound(float, ge=0, le=1),
    "start_steps": Bound(int, ge=0),
    "actor_decay_steps": Bound(int, ge=0, optional=True),
    "diffusion_steps": Bound(int, ge=1),
    "num_samples": Bound(int, ge=1),
    "cql_n_actions": Bound(int, ge=1),
    "policy_freq": Bound(int, ge=1),
    "dropout_rate": Bound(float, ge=0, lt=1),
    "actor_steps": Bound(int, ge=1),
}


def check_bounds(cfg: Config, bounds: Mapping[str, Bound]) -> Config:
    """Raise a one-line :class:`ConfigError` for the first value outside its bounds; return ``cfg``."""
    for key, bound in bounds.items():
        if key in cfg and not bound.accepts(cfg[key]):
            raise ConfigError(
                f"config value {key}={cfg[key]!r} is invalid: it must be {bound.describe()}",
                f"pass e.g. --set {key}=... with {bound.describe()}",
            )
    return cfg
