"""The unit a generator produces: one episode of arrays plus JSON metadata."""

from __future__ import annotations

import dataclasses
from typing import Any, Protocol

import numpy as np

REQUIRED_KEYS = ("observations", "actions", "rewards", "terminals", "timeouts")


@dataclasses.dataclass
class Episode:
    """One episode.

    ``arrays`` holds, for an episode of T transitions:

    - ``observations`` (T+1, ...) float32 – the observation *after* each reset/step;
      for dict observations use one key per part: ``observations/proprio`` ...
    - ``actions`` (T, A) float32, ``rewards`` (T,) float32,
      ``terminals`` (T,) bool (true end of the MDP), ``timeouts`` (T,) bool (time limit)
    - ``states`` (T+1, S) float64 – :meth:`MujocoEnv.get_state`, to replay/re-render
    - any ``infos/<name>`` of length T (per transition) or T+1 (per step).

    Arrays with T+1 rows are *step-aligned*, with T rows *transition-aligned*.
    ``meta`` is JSON-serializable per-episode information (task combination,
    operator skill, domain parameters, policy snapshot, ...).
    """

    arrays: dict[str, np.ndarray]
    meta: dict[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def num_transitions(self) -> int:
        return int(len(self.arrays["actions"]))

    def validate(self) -> None:
        keys = set(self.arrays)
        obs_keys = [k for k in keys if k == "observations" or k.startswith("observations/")]
        missing = [k for k in REQUIRED_KEYS if k != "observations" and k not in keys]
        if not obs_keys:
            missing.insert(0, "observations")
        if missing:
            raise ValueError(f"episode is missing arrays {missing}")
        t = self.num_transitions
        for k, v in self.arrays.items():
            if not isinstance(v, np.ndarray):
                raise TypeError(f"episode array {k!r} is {type(v).__name__}, expected np.ndarray")
            if len(v) not in (t, t + 1):
                raise ValueError(f"episode array {k!r} has {len(v)} rows; expected {t} or {t + 1} (T={t})")
        for k in obs_keys + (["states"] if "states" in keys else []):
            if len(self.arrays[k]) != t + 1:
                raise ValueError(f"{k!r} must have T+1={t + 1} rows, has {len(self.arrays[k])}")
        for k in ("actions", "rewards", "terminals", "timeouts"):
            if len(self.arrays[k]) != t:
                raise ValueError(f"{k!r} must have T={t} rows, has {len(self.arrays[k])}")
        if t and self.arrays["terminals"][:-1].any():
            raise ValueError("only the last transition of an episode may be terminal")


class EpisodeGenerator(Protocol):
    """What a dataset generator implements (``DatasetSpec.generator`` points at the class).

    The class is constructed once per worker process with ``DatasetSpec.generator_kwargs``
    (and ``task_id=``), then asked for episodes by global index.  ``episode`` must be a
    pure function of ``(index, rng)``: the same inputs give the same bytes, whatever
    process or order it runs in.  ``version`` names the generator's code revision; an optional
    ``name`` is what manifests call it (default: its "module:Class"), see
    :func:`d5rl.datasets.generation.producer_name`.
    """

    version: str

    def episode(self, index: int, rng: np.random.Generator) -> Episode: ...
