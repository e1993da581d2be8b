"""The training loop's settings: one typed source of defaults, their bounds, the routing of ``--set key=value``
values to the agent's or the loop's config, and :class:`RunSpec`, everything one run is configured by.
(Per-task values, and the resolver that makes a run spec from them: :mod:`d5rl.settings`.)"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

from d5rl.agents.config import Bound, Config, ConfigError
from d5rl.errors import is_int


def get_train_config() -> Config:
    return Config(
        eval_interval=10_000,  # updates (offline) / env steps (online) between evaluations (D5RL kitchen: 10k)
        eval_episodes=10,  # episodes per evaluation (D5RL: 50 kitchen, 100 A1 at the end, 20 WidowX)
        final_eval_episodes=None,  # episodes of the evaluation at the end (None = eval_episodes)
        eval_envs=5,  # environments stepped in lockstep during evaluation (batched inference)
        eval_processes=False,  # one process per evaluation env (gymnasium AsyncVectorEnv)
        log_interval=1_000,  # steps between metric rows
        checkpoint_interval=50_000,  # steps between checkpoints (online: at the next episode end)
        updates_per_call=8,  # offline updates per jit call via lax.scan (state agents; pixel agents use 1)
        frame_stack=None,  # stacked frames for pixel observations (None = 3 for pixels, 1 for states)
        offline_ratio=None,  # share of online-phase batches from the offline data (None = agent's, else 0.5)
        start_steps=None,  # random-action env steps before online updates (None = agent's start_steps, else 0)
        buffer_capacity=None,  # online replay capacity (None = online_steps; pixels: at most 20k, ~3 GB at 64²×2 cams)
        dataset_episodes=None,  # train on the first N dataset episodes (None = all)
        dataset_in_memory_gb=None,  # read dataset arrays up to this size into RAM (None = 1 GiB): camera frames
        # held in RAM are decoded once, not at every batch (several x faster sampling where RAM allows)
        save_video=False,  # record the first episode of every evaluation
        tensorboard=True,  # also write TensorBoard events if tensorboardX / torch is installed
        progress=True,  # tqdm progress bar with updates/s
    )


# Settings that change how a run executes, never what it computes (a grid may resume or rerun a cell with
# other values of these and it stays the same cell).  Evaluation episodes reset with fixed seeds whatever the
# number of environments or processes stepping them (tests/training/test_parts.py).
EXECUTION_KEYS = (
    "checkpoint_interval",
    "dataset_in_memory_gb",
    "eval_envs",
    "eval_processes",
    "progress",
    "tensorboard",
)

# What each training setting may be (checked before any work; see get_train_config for meanings).
TRAIN_BOUNDS = {
    "eval_interval": Bound(int, ge=0),
    "eval_episodes": Bound(int, ge=1),
    "final_eval_episodes": Bound(int, ge=1, optional=True),
    "eval_envs": Bound(int, ge=1),
    "log_interval": Bound(int, ge=1),
    "checkpoint_interval": Bound(int, ge=1),
    "updates_per_call": Bound(int, ge=1),
    "frame_stack": Bound(int, ge=1, optional=True),
    "offline_ratio": Bound(float, ge=0, le=1, optional=True),
    "start_steps": Bound(int, ge=0, optional=True),
    "buffer_capacity": Bound(int, ge=1, optional=True),
    "dataset_episodes": Bound(int, ge=1, optional=True),
    "dataset_in_memory_gb": Bound(float, ge=0, optional=True),
}


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """Everything one run is configured by, resolved once (:func:`d5rl.settings.resolve`) and passed whole to
    :func:`d5rl.training.loop.train`; ``d5rl train --show-config`` prints :meth:`to_json` of the same object, and
    the run's ``config.json`` starts with it."""

    algo: str  # the agent's canonical name
    task_id: str
    agent: Config  # the agent's settings (the trainer fills the values it takes from the data)
    train: Config  # the training loop's settings (get_train_config)
    offline_steps: int
    online_steps: int
    seed: int = 0

    def to_json(self) -> dict:
        return {
            "algo": self.algo,
            "task_id": self.task_id,
            "offline_steps": self.offline_steps,
            "online_steps": self.online_steps,
            "agent": self.agent.to_dict(),
            "train": self.train.to_dict(),
            "seed": self.seed,
        }


def final_eval_episodes(train: Mapping) -> int:
    """How many episodes the evaluation at the end of a run with these loop settings has."""
    return int(train["final_eval_episodes"] or train["eval_episodes"])


def check_run(offline_steps, online_steps, seed) -> None:
    """One-line errors for step counts and seeds that cannot make a run."""
    for name, v in (("--offline-steps", offline_steps), ("--online-steps", online_steps), ("--seed", seed)):
        if not is_int(v, lo=0):
            raise ConfigError(f"{name} must be a non-negative integer, got {v!r}", f"pass e.g. {name} 0")
    if offline_steps == 0 and online_steps == 0:
        raise ConfigError(
            "nothing to train: --offline-steps and --online-steps are both 0",
            "pass --offline-steps N (and/or --online-steps N)",
        )


def split_overrides(overrides, agent_config: Config, train_config: Config) -> tuple[Config, Config]:
    """Apply ``key=value`` overrides to whichever config owns the key (training keys first)."""
    if not overrides:
        return agent_config, train_config
    items = overrides.items() if isinstance(overrides, Mapping) else [tuple(o.split("=", 1)) for o in overrides]
    agent_items, train_items = [], []
    for item in items:
        if len(item) != 2:
            raise ConfigError(f"override {item[0]!r} is not key=value", "write e.g. --set batch_size=128")
        k, v = item[0].strip(), item[1]
        target = train_items if k in train_config else agent_items if k in agent_config else None
        if target is None:
            raise ConfigError(
                f"unknown config key {k!r}",
                f"agent keys: {sorted(agent_config)}; training keys: {sorted(train_config)}",
            )
        target.append((k, v))

    def apply(cfg, pairs):
        if not pairs:
            return cfg
        if isinstance(overrides, Mapping):
            return cfg.override(dict(pairs))
        return cfg.override([f"{k}={v}" for k, v in pairs])

    return apply(agent_config, agent_items), apply(train_config, train_items)
