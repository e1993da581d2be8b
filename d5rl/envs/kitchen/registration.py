"""Standard Franka Kitchen task ids."""

from d5rl.envs.kitchen.subtasks import MIXED, PARTIAL
from d5rl.registry import DatasetSpec, TaskSpec, register

MAX_EPISODE_STEPS = 280  # control steps of 0.08 s (the D5RL release's standard kitchen)

STANDARD_DATASET = DatasetSpec(
    name="kitchen-standard",
    # 1: demonstrator without detours or pauses (generator kitchen-standard-demos-6); 2: the same generator
    # with portable numerics (the same bytes on every x86-64 CPU)
    version=2,
    generator="d5rl.production.kitchen.data:KitchenStandardGenerator",
    numerics="portable",
    num_episodes=563,
    episodes_per_shard=16,
    description="scripted demonstrations of 22 four-subtask combinations in a fixed order (paper: 563 episodes)",
    derived="d5rl.production.kitchen.data:renders",
)
HUMAN_DATASET = DatasetSpec(
    name="kitchen-standard-human",
    version=1,
    generator=None,
    importer="d5rl.production.kitchen.human:KitchenHumanImport",
    num_episodes=0,  # as many as the imported file holds
    episodes_per_shard=16,
    description="the relay-policy-learning human demonstrations the paper used, imported with "
    "`d5rl import-kitchen-human` (Minari D4RL/kitchen/*-v2 or a D4RL kitchen file)",
    derived="d5rl.production.kitchen.data:renders",
)
SCORE = (
    "fraction of the 4 target subtasks whose object reached its goal configuration during the episode "
    "(info['score'] at the episode's end; 1.0 = all four)"
)

STATE = "30 joint positions (9 robot, 21 objects)"
for name, tasks, desc in (
    ("mixed", MIXED, "microwave, kettle, light switch, slide cabinet (this set appears in the data)"),
    ("partial", PARTIAL, "microwave, kettle, bottom burner, light switch (never together in the data)"),
):
    # each task twice: from the cameras (the benchmark) and, as "-state", from the joint positions
    for suffix, obs, what in (("", "pixels", "cameras + proprioception"), ("-state", "state", STATE)):
        register(
            TaskSpec(
                id=f"kitchen-standard-{name}{suffix}-v0",
                entry_point="d5rl.envs.kitchen.task:KitchenEnv",
                max_episode_steps=MAX_EPISODE_STEPS,
                description=f"Franka Kitchen, {what}: {desc}",
                env_kwargs={"tasks": tasks, **({"obs_mode": "state"} if obs == "state" else {})},
                dataset=STANDARD_DATASET,
                relabel="d5rl.production.kitchen.data:relabel",
                score=None,
                score_from="info",
                score_definition=SCORE,
                group="kitchen-standard",
                observation=obs,
                dataset_variants={"human": HUMAN_DATASET},  # kitchen-standard-<name>[-state]-human-v0
            )
        )

import d5rl.envs.kitchen.randomized.registration  # noqa: E402,F401  (randomized kitchen ids)
