"""Randomized Franka Kitchen task ids (imported by the kitchen family's registration)."""

from d5rl.envs.kitchen.subtasks import MIXED, PARTIAL
from d5rl.registry import DatasetSpec, TaskSpec, register

MAX_EPISODE_STEPS = 500  # control steps of 0.08 s (the paper's randomized kitchen)


def _dataset(mode: str, n: int, desc: str) -> DatasetSpec:
    return DatasetSpec(
        name=f"kitchen-randomized-{mode}",
        version=3,  # what each version changed: CHANGELOG.md
        generator="d5rl.production.kitchen.randomized.data:RandomizedKitchenGenerator",
        num_episodes=n,
        episodes_per_shard=16,
        generator_kwargs={"mode": mode},
        description=desc,
        derived="d5rl.production.kitchen.randomized.data:renders",
    )


SCORE = (
    "fraction of the 4 target subtasks whose object reached its goal configuration during the episode "
    "(info['score'] at the episode's end; 1.0 = all four)"
)
for task_name, dataset_mode, tasks, n, desc in (
    ("demos", "demos", MIXED, 500, "one skilled operator, mixed subtasks in varied orders (paper: 500 episodes)"),
    ("mixed", "play", MIXED, 1000, "play data from operators of several skills, 2-6 objects (paper: 1,000)"),
    ("partial", "play", PARTIAL, 1000, "play data; the partial task's four objects never together (paper: 1,000)"),
    ("suboptimal", "suboptimal", MIXED, 500, "unskilled operators on the mixed subtasks (not benchmarked; paper: 500)"),
):
    for suffix, obs, what in (("", "pixels", "3 cameras 128x128"), ("-state", "state", "30 joint positions")):
        register(
            TaskSpec(
                id=f"kitchen-randomized-{task_name}{suffix}-v0",
                entry_point="d5rl.envs.kitchen.randomized.task:RandomizedKitchenEnv",
                max_episode_steps=MAX_EPISODE_STEPS,
                description=f"Randomized Franka Kitchen (new domain every reset), {what}: {desc}",
                env_kwargs={"tasks": tasks, **({"obs_mode": "state"} if obs == "state" else {})},
                dataset=_dataset(dataset_mode, n, desc),
                relabel="d5rl.production.kitchen.data:relabel",
                score=None,
                score_from="info",
                score_definition=SCORE,
                group="kitchen-randomized",
                observation=obs,
            )
        )
