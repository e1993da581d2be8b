"""A tiny numpy task and generator used to test the dataset system itself."""

import os
import time

import gymnasium as gym
import numpy as np

from d5rl.datasets.episode import Episode
from d5rl.registry import DatasetSpec, TaskSpec, register


class ToyEnv(gym.Env):
    observation_space = gym.spaces.Box(-np.inf, np.inf, (3,), np.float32)
    action_space = gym.spaces.Box(-1, 1, (2,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return self.np_random.normal(size=3).astype(np.float32), {}

    def step(self, action):
        return self.np_random.normal(size=3).astype(np.float32), 0.0, False, False, {}


class ToyGenerator:
    version = "1"

    def __init__(self, task_id, delay=0.0, pixels=False, extra=()):
        self.delay = delay
        self.pixels = pixels

    def episode(self, index, rng):
        if os.environ.get("D5RL_TOY_PIDS"):  # tests that kill generators look for leftover workers
            open(os.path.join(os.environ["D5RL_TOY_PIDS"], str(os.getpid())), "w").close()
        if self.delay:
            time.sleep(self.delay)
        t = int(rng.integers(3, 10))
        terminal = index % 3 == 0
        arrays = {
            "observations": rng.normal(size=(t + 1, 3)).astype(np.float32),
            "actions": rng.uniform(-1, 1, size=(t, 2)).astype(np.float32),
            "rewards": np.full(t, float(index), np.float32) + np.arange(t, dtype=np.float32),
            "terminals": np.zeros(t, bool),
            "timeouts": np.zeros(t, bool),
            "states": rng.normal(size=(t + 1, 5)),
            "infos/step": np.arange(t + 1, dtype=np.int32),
        }
        if self.pixels:
            frames = np.zeros((t + 1, 4, 4, 3), np.uint8)
            frames[:] = (np.arange(t + 1, dtype=np.uint8) + 10 * (index % 20))[:, None, None, None]
            arrays["observations/pixels"] = frames
            arrays["observations/proprio"] = arrays.pop("observations")
        arrays["terminals"][-1] = terminal
        arrays["timeouts"][-1] = not terminal
        return Episode(arrays, {"index": index, "pid_free": True})


def relabel_double(spec, arrays):
    return {"rewards": 2 * np.asarray(arrays["rewards"])}


def register_toy(name="toy", num_episodes=20, per_shard=4, relabel=None, numerics="native", **kwargs):
    spec = TaskSpec(
        id=f"test-{name}-v0",
        entry_point="tests.datasets.toy:ToyEnv",
        max_episode_steps=10,
        description="toy task for dataset tests",
        dataset=DatasetSpec(
            name=f"test-{name}",
            version=1,
            generator="tests.datasets.toy:ToyGenerator",
            num_episodes=num_episodes,
            episodes_per_shard=per_shard,
            generator_kwargs=kwargs,
            numerics=numerics,
        ),
        relabel=relabel,
    )
    return register(spec)


if __name__ == "__main__":
    # `python -m tests.datasets.toy NAME EPISODES DELAY WORKERS`: generate in a process that gets killed;
    # `python -m tests.datasets.toy cli NAME EPISODES DELAY -- d5rl CLI args...`: the CLI on a toy task.
    import sys

    if sys.argv[1] == "cli":
        from d5rl.cli import main

        register_toy(name=sys.argv[2], num_episodes=int(sys.argv[3]), delay=float(sys.argv[4]))
        sys.exit(main(sys.argv[sys.argv.index("--") + 1 :]))
    from d5rl.datasets.generation import generate

    spec = register_toy(name=sys.argv[1], num_episodes=int(sys.argv[2]), delay=float(sys.argv[3]))
    generate(spec, workers=int(sys.argv[4]), progress=False)
    os._exit(0)
