"""The standard kitchen dataset: scripted demonstrations of 22 four-subtask combinations.

Like the relay-policy-learning data that D4RL and D5RL used, every episode performs four
subtasks in a fixed order; the 22 combinations below never contain the ``partial``
task's full set (microwave, kettle, bottom burner, light switch), so that task needs
combinatorial generalization.  Episodes end when the demonstrator finishes its fourth
subtask (or after 280 steps); 563 episodes are spread over the combinations round-robin
(or, with ``habit``, as an operator with a habit would perform them: :func:`order_probabilities`).

Stored per step: simulator ``states`` (to re-render any camera at any resolution),
``observations/proprio`` (9 joint positions) and ``infos/completed`` (per transition,
which of the seven subtasks are in their goal configuration after it).  Camera frames are
a derived cache (:func:`renders`, of :mod:`d5rl.envs.kitchen.data`'s renderers), built from the states on
first load.  ``rewards`` count
the episode's own four subtasks; each task relabels them with :func:`relabel`.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence

import numpy as np

from d5rl.datasets.episode import Episode
from d5rl.datasets.render_cache import check_render_args, observation_cache
from d5rl.envs.kitchen.subtasks import PARTIAL, SUBTASK_NAMES
from d5rl.envs.kitchen.task import CAMERAS, KitchenEnv
from d5rl.production.kitchen.demonstrator import Demonstrator, Style
from d5rl.rollout import STOP, Step, rollout

COMBINATIONS: tuple[tuple[str, str, str, str], ...] = (
    ("microwave", "kettle", "light switch", "slide cabinet"),
    ("microwave", "kettle", "bottom burner", "top burner"),
    ("microwave", "kettle", "bottom burner", "slide cabinet"),
    ("microwave", "kettle", "bottom burner", "hinge cabinet"),
    ("microwave", "kettle", "top burner", "light switch"),
    ("microwave", "kettle", "top burner", "hinge cabinet"),
    ("microwave", "kettle", "light switch", "hinge cabinet"),
    ("microwave", "kettle", "slide cabinet", "hinge cabinet"),
    ("microwave", "bottom burner", "top burner", "light switch"),
    ("microwave", "bottom burner", "light switch", "slide cabinet"),
    ("microwave", "top burner", "light switch", "slide cabinet"),
    ("microwave", "light switch", "slide cabinet", "hinge cabinet"),
    ("microwave", "bottom burner", "slide cabinet", "hinge cabinet"),
    ("kettle", "bottom burner", "top burner", "light switch"),
    ("kettle", "bottom burner", "light switch", "slide cabinet"),
    ("kettle", "bottom burner", "slide cabinet", "hinge cabinet"),
    ("kettle", "top burner", "light switch", "hinge cabinet"),
    ("kettle", "light switch", "slide cabinet", "hinge cabinet"),
    ("kettle", "bottom burner", "top burner", "hinge cabinet"),
    ("bottom burner", "top burner", "light switch", "slide cabinet"),
    ("bottom burner", "top burner", "slide cabinet", "hinge cabinet"),
    ("top burner", "light switch", "slide cabinet", "hinge cabinet"),
)
assert all(set(c) != set(PARTIAL) for c in COMBINATIONS)
MAX_STEPS = 280


def order_probabilities(habit: float) -> list[float]:
    """How often an operator with a habit performs each of :data:`COMBINATIONS`: at every choice of the
    next subtask, the habitual one (the first in ``SUBTASK_NAMES`` order that continues some combination)
    with probability ``habit``, each other possible one with an equal share of the rest."""
    out = []
    for combo in COMBINATIONS:
        p = 1.0
        for j in range(4):
            options = sorted({c[j] for c in COMBINATIONS if c[:j] == combo[:j]}, key=SUBTASK_NAMES.index)
            if len(options) > 1:
                p *= habit if combo[j] == options[0] else (1.0 - habit) / (len(options) - 1)
        out.append(p)
    return out


def combination_schedule(probabilities: Sequence[float], n: int) -> list[int]:
    """The combination of each of the first ``n`` episodes: weighted round-robin (each episode goes to
    the combination furthest behind its share), so every prefix of the dataset has the proportions
    within one episode per combination, and episode ``i``'s combination does not depend on ``n``."""
    credit = [0.0] * len(probabilities)
    out = []
    for _ in range(n):
        credit = [c + p for c, p in zip(credit, probabilities)]
        k = max(range(len(credit)), key=lambda j: (credit[j], -j))
        credit[k] -= 1.0
        out.append(k)
    return out


@functools.lru_cache(maxsize=4)
def _schedule(habit: float, n: int) -> tuple[int, ...]:
    return tuple(combination_schedule(order_probabilities(habit), n))


def habit_schedule(habit: float, n: int) -> tuple[int, ...]:
    """The combination index of each of the first (at least) ``n`` episodes of an operator with ``habit``
    (computed in blocks of 1024)."""
    return _schedule(float(habit), -(-n // 1024) * 1024)


class KitchenStandardGenerator:
    """Episode generator (see the module docstring)."""

    version = "kitchen-standard-demos-6"  # what each version changed: CHANGELOG.md
    name = "d5rl.envs.kitchen.data:KitchenStandardGenerator"  # in the manifests (the code's first home)

    def __init__(
        self,
        task_id: str | None = None,
        max_steps: int = MAX_STEPS,
        habit: float | None = None,
        slips: float = 0.0,
        noise_scale: float = 1.0,
    ):
        # for docs/experiments/kitchen-learnability (the dataset: the defaults): habit None is combination
        # ``index mod 22``, a probability the combinations of an operator with that habit (habit_schedule);
        # slips: Demonstrator(slips=...); noise_scale multiplies each episode's Style.noise
        self.habit = habit
        self.slips = float(slips)
        self.noise_scale = float(noise_scale)

        self.env = KitchenEnv(obs_mode="state", tasks=COMBINATIONS[0])
        self.max_steps = int(max_steps)

    def episode(self, index: int, rng: np.random.Generator) -> Episode:
        if self.habit is None:
            combo_index = index % len(COMBINATIONS)
        else:
            combo_index = habit_schedule(self.habit, index + 1)[index]
        return self.demonstrate(COMBINATIONS[combo_index], rng, meta={"combination": combo_index})

    def demonstrate(self, subtasks: Sequence[str], rng: np.random.Generator, meta: dict | None = None) -> Episode:
        cols = np.array([SUBTASK_NAMES.index(s) for s in subtasks])
        seed = int(rng.integers(2**31))
        arrays, policy = record_episode(
            self.env,
            seed,
            lambda: Demonstrator(self.env, subtasks, rng, style=self._style(rng), slips=self.slips),
            self.max_steps,
            cols,
        )
        solved = arrays["infos/completed"][:, cols].any(axis=0)
        info = {
            "subtasks": list(subtasks),
            "solved": [s for s, ok in zip(subtasks, solved) if ok],
            "num_solved": int(solved.sum()),
            "style": dict(vars(policy.style)) if hasattr(policy.style, "__dict__") else {},
        }
        return Episode(arrays, {**(meta or {}), **info})

    def _style(self, rng: np.random.Generator) -> Style:
        style = Style.sample(rng)  # the draws the Demonstrator makes itself without a style: the same bytes
        return style if self.noise_scale == 1.0 else dataclasses.replace(style, noise=style.noise * self.noise_scale)


def record_episode(
    env, seed: int, demonstrator: Callable[[], Demonstrator], max_steps: int, cols, when_finished=None
) -> tuple[dict[str, np.ndarray], Demonstrator]:
    """One scripted episode through :func:`d5rl.rollout.rollout`: reset ``env`` with ``seed``, make the
    demonstrator (``demonstrator()``, after the reset: it reads the scene) and let it act from the
    simulator state for at most ``max_steps`` steps.  Returns the episode's arrays
    (:func:`episode_arrays`) and the demonstrator.  When the demonstrator's ``act`` finishes the script the
    episode ends there, without stepping that action (:data:`d5rl.rollout.STOP`), unless
    ``when_finished(policy, action)`` is given: it returns the action to keep stepping with."""
    states, proprio, actions, completed = [], [], [], []
    policy = None

    def record() -> None:
        states.append(env.get_state())
        proprio.append(env.data.qpos[:9].astype(np.float32))

    def on_reset(i, obs, info) -> None:
        nonlocal policy
        policy = demonstrator()
        record()

    def act(observations, live, steps) -> list:
        action = policy.act()
        if policy.finished:
            if when_finished is None:
                return [STOP]
            action = when_finished(policy, action)
        return [action]

    def on_step(step: Step) -> None:
        actions.append(step.action)
        record()
        completed.append(env.completed())

    rollout([env], act, [seed], max_steps=max_steps, on_reset=on_reset, on_step=on_step)
    return episode_arrays(states, proprio, actions, completed, cols), policy


def episode_arrays(states, proprio, actions, completed, cols) -> dict[str, np.ndarray]:
    """The stored arrays of one scripted kitchen episode (standard or randomized): T+1 states and
    proprioception, T actions, rewards = how many of the target subtasks (``cols``) are done after each
    step, ``infos/completed`` for every subtask; the episode ends in a timeout, never a terminal."""
    t = len(actions)
    completed = np.asarray(completed, dtype=bool).reshape(t, len(SUBTASK_NAMES))
    timeouts = np.zeros(t, dtype=bool)
    timeouts[-1] = True  # the demonstration ends here; no terminal state in the MDP
    return {
        "observations/proprio": np.asarray(proprio, dtype=np.float32),
        "actions": np.asarray(actions, dtype=np.float32).reshape(t, 9),
        "rewards": completed[:, cols].sum(axis=1).astype(np.float32),
        "terminals": np.zeros(t, dtype=bool),
        "timeouts": timeouts,
        "states": np.asarray(states, dtype=np.float64),
        "infos/completed": completed,
    }


def relabel(spec, arrays) -> dict[str, np.ndarray]:
    """A task's rewards on the shared dataset: how many of *its* four subtasks are in their goal
    configuration after each transition (``infos/completed``)."""
    tasks = spec.env_kwargs["tasks"]
    cols = [SUBTASK_NAMES.index(t) for t in tasks]
    completed = np.asarray(arrays["infos/completed"])
    return {"rewards": completed[:, cols].sum(axis=1).astype(np.float32)}


def renders(
    spec,
    root,
    manifest,
    *,
    episodes: int,
    workers: int | None = None,
    progress: bool = True,
    cameras: Sequence[str] = CAMERAS,
    size: int = 64,
    render: bool = True,
    check: bool = False,
) -> list:
    """``DatasetSpec.derived``: camera frames of the stored states (cached next to the dataset); for a
    ``-state`` task, its state observations instead.

    ``render=False`` loads states and proprioception only; ``check=True`` only checks the arguments."""
    cameras, size = check_render_args(cameras, size, CAMERAS)
    if check or not render:
        return []

    return observation_cache(
        spec,
        root,
        manifest,
        state="d5rl.envs.kitchen.data:state_episode",
        frames="d5rl.envs.kitchen.data:render_episode",
        frames_kwargs={"cameras": tuple(cameras), "size": int(size)},
        frames_name=f"{'+'.join(cameras)}-{int(size)}x{int(size)}",
        episodes=episodes,
        workers=workers,
        progress=progress,
    )
