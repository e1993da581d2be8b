"""A numpy replay buffer for online transitions (flat or dict observations)."""

from __future__ import annotations

from typing import Any

import numpy as np

FIELDS = ("actions", "rewards", "masks", "mc_returns", "next_actions")
# mc_returns of transitions whose episode has not finished yet: no lower bound.
NO_RETURN = np.float32(-1e9)


def _leaves(obs) -> dict[str, np.ndarray]:
    return dict(obs) if isinstance(obs, dict) else {"": obs}


class ReplayBuffer:
    """Fixed-capacity FIFO of transitions; ``sample`` gives the same batch dict as ``Dataset.sample``."""

    def __init__(self, example_obs, action_dim: int, capacity: int):
        self.capacity = int(capacity)
        self.dict_obs = isinstance(example_obs, dict)
        self.obs = {
            k: np.empty((self.capacity,) + np.shape(v), np.asarray(v).dtype) for k, v in _leaves(example_obs).items()
        }
        self.next_obs = {k: np.empty_like(v) for k, v in self.obs.items()}
        self.data = {
            "actions": np.empty((self.capacity, action_dim), np.float32),
            "rewards": np.empty(self.capacity, np.float32),
            "masks": np.empty(self.capacity, np.float32),
            "mc_returns": np.full(self.capacity, NO_RETURN, np.float32),
            # the action taken at the next step of the same episode (the last step repeats its own)
            "next_actions": np.empty((self.capacity, action_dim), np.float32),
        }
        self.size = 0
        self.pos = 0
        self._prev: int | None = None  # the previous transition of the episode being collected

    def __len__(self) -> int:
        return self.size

    def insert(self, obs, action, reward, mask, next_obs) -> int:
        i = self.pos
        for k, v in _leaves(obs).items():
            self.obs[k][i] = v
        for k, v in _leaves(next_obs).items():
            self.next_obs[k][i] = v
        self.data["actions"][i] = action
        self.data["rewards"][i] = reward
        self.data["masks"][i] = mask
        self.data["mc_returns"][i] = NO_RETURN
        self.data["next_actions"][i] = action
        if self._prev is not None:
            self.data["next_actions"][self._prev] = action
        self._prev = i
        self.pos = (self.pos + 1) % self.capacity
        self.size = min(self.size + 1, self.capacity)
        return i

    def end_episode(self) -> None:
        """The episode being collected ended: the next insert starts a new one."""
        self._prev = None

    def set_mc_returns(self, indices: list[int], rewards: list[float], gamma: float, bootstrap: float = 0.0) -> None:
        """Fill the discounted reward-to-go of one finished episode (indices in time order)."""
        acc = bootstrap
        for i, r in zip(reversed(indices), reversed(rewards)):
            acc = r + gamma * acc
            self.data["mc_returns"][i] = acc

    def _obs(self, store, idx):
        out = {k: v[idx] for k, v in store.items()}
        return out if self.dict_obs else out[""]

    def sample(self, batch_size: int, rng: np.random.Generator) -> dict[str, Any]:
        idx = rng.integers(0, self.size, size=batch_size)
        batch = {k: v[idx] for k, v in self.data.items()}
        batch["observations"] = self._obs(self.obs, idx)
        batch["next_observations"] = self._obs(self.next_obs, idx)
        return batch

    # --- checkpoints ---------------------------------------------------------------------------
    def state_dict(self) -> dict[str, np.ndarray]:
        n = self.size
        out = {f"obs/{k}": v[:n] for k, v in self.obs.items()}
        out.update({f"next_obs/{k}": v[:n] for k, v in self.next_obs.items()})
        out.update({f"data/{k}": v[:n] for k, v in self.data.items()})
        out["meta"] = np.array([self.size, self.pos, self.capacity], np.int64)
        return out

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        size, pos, capacity = (int(x) for x in state["meta"])
        if capacity != self.capacity:
            raise ValueError(f"checkpointed buffer has capacity {capacity}, this one {self.capacity}")
        self.size, self.pos = size, pos
        for k in self.obs:
            self.obs[k][:size] = state[f"obs/{k}"]
            self.next_obs[k][:size] = state[f"next_obs/{k}"]
        for k in self.data:
            self.data[k][:size] = state[f"data/{k}"]
