"""A1 datasets: the data-collecting agents' replay buffers, regenerated from policy snapshots.

The paper's A1 data are the replay buffers of RL agents, "from first exploration to
expert".  Training those agents (``d5rl.production.a1.experts``) takes hours, so the
repository ships what training produced: for each agent, its actor at every
snapshot and how many episodes each snapshot collected (``policies/<agent>/log.json``).
Every training episode is re-collected by the snapshot that was acting then (uniform random actions before
learning started), with the SAC policy's own sampling noise.  Per-step reward terms
are stored in ``infos/*`` so each task relabels rewards for its own target.

A v1 episode's scene is drawn at reset (RunToward: smooth or bumpy floor, its heights, the floor's
friction, the trunk's mass, the goals; hiking: the course), so its ``meta`` keeps the env's reset seed
(``reset_seed``) and :func:`replay_env` rebuilds the scene from it: stored states only make sense on
the floor they were collected on.
"""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path

import numpy as np

from d5rl.datasets.episode import Episode
from d5rl.envs.a1 import rewards
from d5rl.envs.a1.published import POLICY_DIR, agent_log
from d5rl.errors import D5RLError
from d5rl.production.a1.agents import AGENTS, EPISODE_STEPS, make_env
from d5rl.production.a1.buffers import episode_table
from d5rl.production.a1.policy import SnapshotPolicy
from d5rl.rollout import rollout

INFO_KEYS = ("forward_speed", "standing", "energy", "heading_error")


def policy_digest(agent: str, policy_dir: Path | None = None) -> str:
    """sha256 over the names and bytes of ``agent``'s policy files in ``policy_dir`` (default: the policy
    directory, :data:`POLICY_DIR`), cached per file sizes and times."""
    folder = Path(POLICY_DIR if policy_dir is None else policy_dir) / agent
    files = sorted(p for p in folder.iterdir() if p.is_file()) if folder.is_dir() else []
    return _digest(tuple((str(p), p.stat().st_size, p.stat().st_mtime_ns) for p in files))


@functools.lru_cache(maxsize=64)
def _digest(files: tuple[tuple[str, int, int], ...]) -> str:
    h = hashlib.sha256()
    for path, _, _ in files:
        h.update(Path(path).name.encode() + b"\0")
        h.update(hashlib.sha256(Path(path).read_bytes()).digest())
    return h.hexdigest()


class ReplayBufferGenerator:
    """Episode ``i`` = training episode ``episode_table(agents)[i]``, re-collected by its snapshot."""

    version = "1"
    name = "d5rl.envs.a1.data:ReplayBufferGenerator"  # in the manifests (the code's first home)

    @staticmethod
    def inputs(agents: tuple[str, ...]) -> dict[str, str]:
        """The dataset identity's ``generator_inputs``: a digest of each v1 agent's policy files (its
        snapshots, final policy and training log), so data replayed from trial policies
        (``D5RL_A1_POLICIES``) never pass for the published agents' data.  v0's agents are left out: their
        datasets were made before this key and their policies are fixed in the package."""
        return {a: policy_digest(a) for a in agents if AGENTS[a].env_version == 1}

    def __init__(self, task_id: str, agents: tuple[str, ...]):
        self.agents = tuple(agents)
        self.table = episode_table(self.agents)
        self._envs: dict = {}
        self._policies: dict = {}

    def _env(self, agent):
        if agent not in self._envs:
            self._envs[agent] = make_env(agent)
        return self._envs[agent]

    def _policy(self, agent, seg_i):
        key = (agent, seg_i)
        if key not in self._policies:
            snap = agent_log(agent)["segments"][seg_i]["snapshot"]
            self._policies[key] = SnapshotPolicy(None if snap is None else POLICY_DIR / agent / snap)
        return self._policies[key]

    def episode(self, index: int, rng: np.random.Generator) -> Episode:
        if index >= len(self.table):
            raise D5RLError(f"episode {index} is beyond the {len(self.table)} episodes of the A1 agents' buffers")
        agent, seg_i = self.table[index]
        env, policy = self._env(agent), self._policy(agent, seg_i)
        reset_seed = int(rng.integers(2**31))
        observations, states, actions, rews, terms = [], [], [], [], []
        infos = {k: [] for k in INFO_KEYS}

        def on_reset(i, obs, info):
            observations.append(obs)
            states.append(env.get_state())

        def on_step(s):
            observations.append(s.next_obs)
            states.append(env.get_state())
            actions.append(s.action)
            rews.append(s.reward)
            terms.append(s.terminated)
            for k in INFO_KEYS:
                infos[k].append(s.info[k])

        rollout(
            [env],
            lambda obs, live, steps: [policy(obs[0], rng)],
            [reset_seed],
            max_steps=EPISODE_STEPS,
            on_reset=on_reset,
            on_step=on_step,
        )
        t = len(actions)
        timeouts = np.zeros(t, bool)
        timeouts[-1] = not terms[-1]
        arrays = {
            "observations": np.asarray(observations, np.float32),
            "states": np.asarray(states, np.float64),
            "actions": np.asarray(actions, np.float32),
            "rewards": np.asarray(rews, np.float32),
            "terminals": np.asarray(terms, bool),
            "timeouts": timeouts,
            **{f"infos/{k}": np.asarray(v, np.float32) for k, v in infos.items()},
        }
        seg = agent_log(agent)["segments"][seg_i]
        meta = {
            "agent": agent,
            "agent_target_speed": AGENTS[agent].target_speed,
            "segment": seg_i,
            "snapshot": seg["snapshot"] or "random",
            "training_step": seg["start_step"],
        }
        if AGENTS[agent].env_version == 1:  # v0's scenes are the same in every episode
            meta["reset_seed"] = reset_seed
        return Episode(arrays, meta)


def replay_env(spec, meta: dict, **kwargs):
    """The env a stored v1 episode was collected in, showing that episode's scene (``DatasetSpec.replay``).

    It is the data agent's env (a hiking episode was collected on RunToward's floors, not on the course)
    reset with the episode's ``reset_seed``, which redraws the floor, its friction, the trunk's mass and
    the first goal as they were; ``set_state`` then shows the stored states where they happened, and
    :meth:`~d5rl.envs.a1.v1.A1EnvV1.replay_step` recomputes their observations.  ``kwargs`` go to the
    env (e.g. ``render_mode``).
    """
    if "reset_seed" not in meta or meta.get("agent") not in AGENTS:
        raise D5RLError(
            f"{spec.id}'s episode records no data agent and reset seed to rebuild its scene from",
            f"regenerate the dataset: d5rl generate {spec.id} --force",
        )
    env = make_env(meta["agent"], **kwargs)
    env.reset(seed=int(meta["reset_seed"]))
    return env


def relabel_speed(spec, arrays) -> dict:
    """Rewards of a speed-tracking task (``env_kwargs['target_speed']``) from stored reward terms."""
    target = spec.env_kwargs["target_speed"]
    r = rewards.speed_reward(
        np.asarray(arrays["infos/forward_speed"]),
        np.asarray(arrays["infos/standing"]),
        np.asarray(arrays["infos/energy"]),
        target,
    )
    return {"rewards": r.astype(np.float32)}


def relabel_hiking(spec, arrays) -> dict:
    target = spec.env_kwargs["target_speed"]
    r = rewards.hiking_reward(
        np.asarray(arrays["infos/forward_speed"]),
        np.asarray(arrays["infos/standing"]),
        np.asarray(arrays["infos/energy"]),
        np.asarray(arrays["infos/heading_error"]),
        target,
    )
    return {"rewards": r.astype(np.float32)}
