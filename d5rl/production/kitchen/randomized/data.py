"""Randomized-kitchen datasets: emulated human teleoperation by operators with skill parameters.

Each episode draws a domain (the env's reset), an operator and a subtask list, then runs the
standard kitchen's scripted :class:`~d5rl.production.kitchen.demonstrator.Demonstrator` with the
operator's habits for 500 steps (after the last subtask the operator holds still, with noise).

- ``demos``: one skilled operator, the ``mixed`` task's four subtasks in a random order.
- ``play``: operators of several skill levels, 2-6 random subtasks in random order; no episode
  contains all four ``partial`` subtasks.
- ``suboptimal``: unskilled operators on the ``mixed`` subtasks in random order.

Operators (:class:`Operator`): ``speed`` (phase speed), ``noise`` (smoothed action noise std),
``hesitation`` (chance of a short pause before each phase), ``detour`` (chance of a detour via a
random point), ``give_up`` (chance of abandoning a subtask attempt -- emulating a failed grasp
that is not retried) and ``retries`` (how often a subtask the script did not finish is tried again).  Stored per episode (meta): ``domain`` (re-render exactly with
:func:`d5rl.envs.kitchen.randomized.data.render_episode`), ``operator``, ``subtasks``, ``solved``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from d5rl.datasets.episode import Episode
from d5rl.datasets.render_cache import check_render_args, observation_cache
from d5rl.envs.kitchen.randomized.task import CAMERAS, RandomizedKitchenEnv
from d5rl.envs.kitchen.subtasks import MIXED, PARTIAL, SUBTASK_NAMES
from d5rl.errors import D5RLError
from d5rl.production.kitchen.data import record_episode
from d5rl.production.kitchen.demonstrator import Demonstrator, Style

MAX_STEPS = 500


@dataclasses.dataclass(frozen=True)
class Operator:
    name: str
    speed: tuple[float, float]
    noise: tuple[float, float]
    hesitation: tuple[float, float]
    detour: tuple[float, float]
    give_up: float
    retries: int = 0  # tries again at a subtask the script did not finish (at most this many times)

    def style(self, rng: np.random.Generator):
        return Style(
            speed=float(rng.uniform(*self.speed)),
            noise=float(rng.uniform(*self.noise)),
            pause_prob=float(rng.uniform(*self.hesitation)),
            via_prob=float(rng.uniform(*self.detour)),
        )


SKILLED = Operator(
    "skilled", speed=(1.0, 1.2), noise=(0.01, 0.03), hesitation=(0.0, 0.05), detour=(0.0, 0.1), give_up=0.0, retries=3
)
AVERAGE = Operator(
    "average", speed=(0.8, 1.1), noise=(0.03, 0.08), hesitation=(0.05, 0.2), detour=(0.1, 0.3), give_up=0.04, retries=1
)
NOVICE = Operator(
    "novice", speed=(0.6, 0.9), noise=(0.08, 0.15), hesitation=(0.15, 0.35), detour=(0.3, 0.6), give_up=0.06
)
OPERATORS = {o.name: o for o in (SKILLED, AVERAGE, NOVICE)}
MIXED_ORDER = tuple(MIXED)
MODES = {"demos": (SKILLED,), "play": (SKILLED, AVERAGE, NOVICE), "suboptimal": (AVERAGE, NOVICE)}


def play_subtasks(rng: np.random.Generator) -> list[str]:
    """2-6 subtasks, as many equally often (4 on average), never the partial task's four together."""
    n = int(rng.integers(2, 7))
    while True:  # redraw the set, not its size: rejecting sizes would favour small sets (3.7 on average)
        chosen = [SUBTASK_NAMES[i] for i in rng.permutation(len(SUBTASK_NAMES))[:n]]
        if not set(PARTIAL) <= set(chosen):
            return chosen


class RandomizedKitchenGenerator:
    """Episode generator; ``mode`` is ``demos``, ``play`` or ``suboptimal``."""

    version = "kitchen-randomized-9"  # what each version changed: CHANGELOG.md
    name = "d5rl.envs.kitchen.randomized.data:RandomizedKitchenGenerator"  # in the manifests (the code's first home)

    def __init__(self, task_id: str | None = None, mode: str = "demos", max_steps: int = MAX_STEPS):
        if mode not in MODES:
            raise D5RLError(f"unknown randomized-kitchen dataset mode {mode!r}", f"use one of {list(MODES)}")
        self.mode = mode
        self.env = RandomizedKitchenEnv(obs_mode="state")
        self.max_steps = int(max_steps)

    def episode(self, index: int, rng: np.random.Generator) -> Episode:
        ops = MODES[self.mode]
        op = ops[int(rng.integers(len(ops)))]
        subtasks = play_subtasks(rng) if self.mode == "play" else [MIXED[i] for i in rng.permutation(len(MIXED))]
        return self.demonstrate(subtasks, op, rng)

    def demonstrate(self, subtasks: Sequence[str], op: Operator, rng: np.random.Generator) -> Episode:
        env = self.env
        cols = np.array([SUBTASK_NAMES.index(s) for s in subtasks])
        seed = int(rng.integers(2**31))

        def demonstrator():  # after the reset: the operator's choices in this episode's domain
            attempted = [s for s in subtasks if rng.random() >= op.give_up]
            # an abandoned subtask is still approached for a while (a failed attempt), then dropped
            return Demonstrator(env, attempted, rng, style=op.style(rng), transit_first=True, retries=op.retries)

        hold_noise = np.zeros(9)

        def hold(policy, action):  # after the script: hold still with the operator's slowly varying noise
            nonlocal hold_noise
            hold_noise = 0.8 * hold_noise + 0.2 * rng.normal(0.0, policy.style.noise, 9)
            return np.clip(action + hold_noise, -1, 1).astype(np.float32)

        arrays, policy = record_episode(env, seed, demonstrator, self.max_steps, cols, when_finished=hold)
        solved_any = arrays["infos/completed"].any(axis=0)
        meta = {
            "domain": env.domain.to_json(),  # the reset's info["domain"]
            "operator": op.name,
            "style": dataclasses.asdict(policy.style),
            "subtasks": list(subtasks),
            "attempted": policy.subtasks,
            "solved": [s for s in SUBTASK_NAMES if solved_any[SUBTASK_NAMES.index(s)]],
            "num_solved": int(solved_any.sum()),
        }
        return Episode(arrays, meta)


def renders(
    spec,
    root,
    manifest,
    *,
    episodes: int,
    workers: int | None = None,
    progress: bool = True,
    cameras: Sequence[str] = CAMERAS,
    size: int = 128,
    render: bool = True,
    check: bool = False,
) -> list:
    """``DatasetSpec.derived``: camera frames of the stored states in their domains (cached); for a
    ``-state`` task, its state observations instead.  ``check=True`` only checks the arguments."""
    cameras, size = check_render_args(cameras, size, CAMERAS)
    if check or not render:
        return []

    return observation_cache(
        spec,
        root,
        manifest,
        state="d5rl.envs.kitchen.data:state_episode",
        frames="d5rl.envs.kitchen.randomized.data:render_episode",
        frames_kwargs={"cameras": tuple(cameras), "size": int(size)},
        frames_name=f"{'+'.join(cameras)}-{int(size)}x{int(size)}",
        episodes=episodes,
        workers=workers,
        progress=progress,
    )
