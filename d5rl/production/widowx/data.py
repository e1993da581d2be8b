"""Scripted datasets for the WidowX bin-sorting tasks.

Two datasets of 2,000 episodes each (as in the paper):

``wx-sorting`` (``mode="sorting"``)
    The scripted policy (:mod:`d5rl.production.widowx.scripted`) handles the objects in
    random order, each going to the wrong bin with probability 0.3 (the paper), under
    one of three plans drawn per episode so that, as in the paper, the data are "mostly
    unsuccessful at solving the full task but consistently solve the individual
    segments of the task in separate episodes":

    - ``both`` (probability ``1 - p_one - p_miss``): picks and places both objects in
      succession;
    - ``one`` (``p_one``): picks and places the first object only, then returns home;
    - ``miss`` (``p_miss``): both objects, but the grasp of one of them (either, at
      random) is botched: the gripper closes above it and carries nothing.

    Episodes run the task's full 120 steps.
``wx-pickplace`` (``mode="pickplace"``)
    The policy picks one of the two objects (chosen at random) and places it,
    in its correct bin with probability 0.7; 60-step episodes.

Stored per step: ``observations/proprio`` (joint positions, the task's
proprioception), the full simulator ``states``, ``infos/stage`` (the policy's
stage index, see :data:`scripted.STAGES`) and ``infos/object`` (which of the
handled objects it works on).  ``meta`` holds the episode's domain (objects,
textures, lights, camera), the handling order, the chosen bins, and the
outcome.  Camera images are *not* stored: :func:`d5rl.envs.widowx.data.render_states` re-renders any
view from ``states`` + ``meta``, and :func:`renders` (the ``DatasetSpec.derived``
hook) caches the 128×128 ``observations/pixels/side`` frames next to the dataset
through :mod:`d5rl.datasets.render_cache` when the dataset is loaded.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from d5rl.datasets.episode import Episode
from d5rl.datasets.render_cache import check_render_args, observation_cache
from d5rl.envs.widowx import model as wm
from d5rl.envs.widowx import scene as wscene
from d5rl.envs.widowx.registration import MAX_EPISODE_STEPS
from d5rl.envs.widowx.task import LIFTED_Z, WidowXSortingEnv
from d5rl.production.widowx import scripted
from d5rl.rollout import Step, rollout

PICKPLACE_STEPS = 60


@dataclasses.dataclass(frozen=True)
class Plan:
    """What the scripted policy sets out to do in one episode (see the module docstring)."""

    kind: str  # sorting: "both", "one" or "miss"; "pickplace" for the pickplace data
    objects: list[str]  # in the order the policy handles them (the ones it attempts)
    missed: list[bool]  # the grasp of this object is botched on purpose
    wrong: list[bool]  # this object goes to the wrong bin
    targets: list[str]  # the bin each object goes to


class WidowXScriptedGenerator:
    """Episode generator for both WidowX datasets (see the module docstring)."""

    version = "wx-scripted-4"  # what each version changed: CHANGELOG.md
    name = "d5rl.envs.widowx.data:WidowXScriptedGenerator"  # in the manifests (the code's first home)

    def __init__(
        self,
        task_id: str = "",
        mode: str = "sorting",
        p_wrong: float = 0.3,
        p_one: float = 0.0,
        p_miss: float = 0.0,
        episode_steps: int | None = None,
        noise: float = 0.15,
    ):
        if mode not in ("sorting", "pickplace"):
            raise ValueError(f"mode must be 'sorting' or 'pickplace', got {mode!r}")
        if not (0 <= p_one and 0 <= p_miss and p_one + p_miss <= 1) or (mode == "pickplace" and p_one + p_miss):
            raise ValueError(
                f"p_one={p_one}, p_miss={p_miss}: need p_one, p_miss >= 0 with p_one + p_miss <= 1, "
                "and both 0 for mode='pickplace'"
            )
        self.task_id = task_id
        self.mode = mode
        self.p_wrong = float(p_wrong)
        self.p_one = float(p_one)
        self.p_miss = float(p_miss)
        self.noise = float(noise)
        default = MAX_EPISODE_STEPS if mode == "sorting" else PICKPLACE_STEPS
        self.episode_steps = int(episode_steps or default)
        self._env: WidowXSortingEnv | None = None

    @property
    def env(self) -> WidowXSortingEnv:
        if self._env is None:
            self._env = WidowXSortingEnv(obs_mode="state")
        return self._env

    def draw_plan(self, rng: np.random.Generator) -> Plan:
        """The episode's plan in the scene just reset (its objects)."""
        objects = list(self.env.domain.objects)
        rng.shuffle(objects)
        plan = "pickplace"
        if self.mode == "sorting":
            u = rng.random()
            plan = "one" if u < self.p_one else "miss" if u < self.p_one + self.p_miss else "both"
        if plan in ("pickplace", "one"):
            objects = objects[:1]
        missed = [False] * len(objects)
        if plan == "miss":
            missed[int(rng.integers(len(objects)))] = True
        wrong = [bool(rng.random() < self.p_wrong) for _ in objects]
        targets = [_other(wm.CATEGORY[o]) if w else wm.CATEGORY[o] for o, w in zip(objects, wrong)]
        return Plan(plan, objects, missed, wrong, targets)

    def episode(self, index: int, rng: np.random.Generator) -> Episode:
        env = self.env
        T = self.episode_steps
        proprio = np.empty((T + 1, 8), np.float32)
        states = np.empty((T + 1, env.state_size), np.float64)
        actions = np.empty((T, 5), np.float32)
        rewards = np.empty(T, np.float32)
        stage = np.empty(T + 1, np.int8)
        current = np.empty(T + 1, np.int8)
        first_reward_step: dict[int, int] = {}
        done_step = None
        plan, policy, lifted = None, None, []

        def record(t: int) -> None:
            proprio[t], states[t] = env.proprio(), env.get_state()
            stage[t], current[t] = policy.stage, policy.current

        def on_reset(i, obs, info) -> None:  # the plan and the policy need the scene
            nonlocal plan, policy, lifted
            plan = self.draw_plan(rng)
            policy = scripted.ScriptedSorter(env, plan.objects, plan.targets, rng, noise=self.noise, miss=plan.missed)
            lifted = [False] * len(plan.objects)  # did the object leave the table in the policy's grasp?
            record(0)

        def on_step(step: Step) -> None:
            nonlocal done_step
            t = step.t
            actions[t], rewards[t] = step.action, step.reward
            record(t + 1)
            if policy.stage_name in ("lift", "carry", "release") and policy.current < len(plan.objects):
                name = plan.objects[policy.current]
                lifted[policy.current] |= bool(wscene.object_center(env.model, env.data, name)[2] > LIFTED_Z)
            first_reward_step.setdefault(int(rewards[t]), t)
            if done_step is None and policy.stage_name == "done":
                done_step = t

        (ep,) = rollout(
            [env],
            lambda observations, live, steps: [np.asarray(policy.act(), np.float32)],  # from the simulator state
            [int(rng.integers(2**31 - 1))],
            max_steps=T,
            on_reset=on_reset,
            on_step=on_step,
        )
        info, objects, targets = ep.info, plan.objects, plan.targets
        final_bins = {env.domain.shoe: info["shoe_bin"], env.domain.toy: info["toy_bin"]}
        meta = {
            "domain": env.domain.to_json(),
            "mode": self.mode,
            "plan": plan.kind,  # sorting: "both", "one" or "miss"; "pickplace" for the pickplace data
            "objects": objects,  # in the order the policy handles them (the ones it attempts)
            "missed_grasp": plan.missed,  # the grasp of this object was botched on purpose
            "target_bins": targets,
            "wrong_bin": plan.wrong,
            "final_bins": [final_bins[o] for o in objects],
            "end_bins": {"shoe": info["shoe_bin"], "toy": info["toy_bin"]},  # where the shoe / toy lie at the end
            "placed_as_intended": [final_bins[o] == b for o, b in zip(objects, targets)],
            "lifted": lifted,
            "num_sorted": int(info["num_sorted"]),
            "policy_done_step": done_step,
            "first_step_with_reward": {str(k): v for k, v in sorted(first_reward_step.items()) if k > 0},
        }
        arrays = {
            "observations/proprio": proprio,
            "actions": actions,
            "rewards": rewards,
            "terminals": np.zeros(T, bool),
            "timeouts": np.r_[np.zeros(T - 1, bool), True],
            "states": states,
            "infos/stage": stage,
            "infos/object": current,
        }
        return Episode(arrays, meta)


def _other(bin_name: str) -> str:
    return "toy" if bin_name == "shoe" else "shoe"


def renders(
    spec,
    root,
    manifest,
    *,
    episodes: int,
    workers: int | None = None,
    progress: bool = True,
    size: int = 128,
    render: bool = True,
    check: bool = False,
) -> list:
    """``DatasetSpec.derived``: the ``observations/pixels/side`` frames, cached next to the dataset; for a
    ``-state`` task, its state observations instead.

    ``load_dataset(task, size=64)`` renders another resolution; ``render=False`` loads
    states and proprioception only; ``check=True`` only checks the arguments.
    """
    _, size = check_render_args(None, size)
    if check or not render:
        return []

    return observation_cache(
        spec,
        root,
        manifest,
        state="d5rl.envs.widowx.data:state_episode",
        frames="d5rl.envs.widowx.data:render_episode",
        frames_kwargs={"size": int(size)},
        frames_name=f"side-{int(size)}x{int(size)}",
        episodes=episodes,
        workers=workers,
        progress=progress,
    )
