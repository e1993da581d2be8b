"""Standard Franka Kitchen task ids."""

from d5rl.envs.kitchen.subtasks import MIXED, PARTIAL
from d5rl.registry import DatasetSpec, TaskSpec, register

MAX_EPISODE_STEPS = 280  # control steps of 0.08 s (the D5RL release's standard kitchen)

STANDARD_DATASET = DatasetSpec(
    name="kitchen-standard",
    version=0,
    generator="d5rl.envs.kitchen.data:KitchenStandardGenerator",
    num_episodes=563,
    episodes_per_shard=16,
    description="scripted demonstrations of 22 four-subtask combinations in a fixed order (paper: 563 episodes)",
    derived="d5rl.envs.kitchen.data:renders",
)
SCORE = (
    "fraction of the 4 target subtasks whose object reached its goal configuration during the episode "
    "(info['score'] at the episode's end; 1.0 = all four)"
)

for name, tasks, desc in (
    ("mixed", MIXED, "microwave, kettle, light switch, slide cabinet (this set appears in the data)"),
    ("partial", PARTIAL, "microwave, kettle, bottom burner, light switch (never together in the data)"),
):
    register(
        TaskSpec(
            id=f"kitchen-standard-{name}-v0",
            entry_point="d5rl.envs.kitchen.task:KitchenEnv",
            max_episode_steps=MAX_EPISODE_STEPS,
            description=f"Franka Kitchen, cameras + proprioception: {desc}",
            env_kwargs={"tasks": tasks},
            dataset=STANDARD_DATASET,
            relabel="d5rl.envs.kitchen.data:relabel",
            score=None,
            score_from="info",
            score_definition=SCORE,
            tags=("kitchen", "pixels"),
        )
    )

import d5rl.envs.kitchen.randomized.registration  # noqa: E402,F401  (randomized kitchen ids)
