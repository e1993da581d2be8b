"""WidowX bin-sorting tasks (paper section "Multi-Stage Manipulation with Scripted Data")."""

from __future__ import annotations

from d5rl.registry import DatasetSpec, TaskSpec, register

MAX_EPISODE_STEPS = 120  # control steps of 0.1 s

_ENTRY = "d5rl.envs.widowx.task:WidowXSortingEnv"
_GENERATOR = "d5rl.production.widowx.data:WidowXScriptedGenerator"
_RENDERS = "d5rl.production.widowx.data:renders"  # side-camera frames, rendered from stored states on load
# The normalized score is not a function of the return (the reward counts sorted objects at
# every step): score_from="info" makes evaluators read info["score"] at the episode's end.
_SCORE_DEFINITION = (
    "fraction of the two objects in their correct bin at the end of the episode "
    "(info['score'] at the episode's end = final-step reward / 2; 1.0 = both sorted)"
)

SORTING_DATA = DatasetSpec(
    name="wx-sorting",
    version=3,
    generator=_GENERATOR,
    num_episodes=2000,
    episodes_per_shard=25,
    generator_kwargs={"mode": "sorting", "p_wrong": 0.3, "p_one": 0.25, "p_miss": 0.2},
    derived=_RENDERS,
    description="2,000 scripted episodes (120 steps) sorting the two objects in succession (55%), only the "
    "first one (25%), or both with one grasp botched (20%); each object goes to the wrong bin with "
    "probability 0.3. States + proprio; camera frames are re-rendered.",
)
PICKPLACE_DATA = DatasetSpec(
    name="wx-pickplace",
    version=3,
    generator=_GENERATOR,
    num_episodes=2000,
    episodes_per_shard=50,
    generator_kwargs={"mode": "pickplace", "p_wrong": 0.3},
    derived=_RENDERS,
    description="2,000 scripted episodes (60 steps) picking one of the two objects and placing it "
    "(correct bin with probability 0.7). States + proprio; camera frames are re-rendered.",
)
STATE = "joint positions, tip and object poses (25)"

for name, dataset, desc in (
    (
        "sorting",
        SORTING_DATA,
        "data: a scripted policy sorting one or both objects, mostly failing the whole "
        "task (wrong bin 30% of the time).",
    ),
    ("sorting-pickplacedata", PICKPLACE_DATA, "the agent must chain two of the data's single pick-and-places."),
):
    # each task twice: from the side camera (the benchmark) and, as "-state", from simulator state
    for suffix, obs, what in (("", "pixels", "a 128x128 side camera + joint positions"), ("-state", "state", STATE)):
        register(
            TaskSpec(
                id=f"wx-{name}{suffix}-v0",
                entry_point=_ENTRY,
                max_episode_steps=MAX_EPISODE_STEPS,
                description=f"WidowX 250 sorts a shoe and a toy into their bins from {what}; {desc}",
                env_kwargs={"obs_mode": "state"} if obs == "state" else {},
                dataset=dataset,
                score_from="info",
                score_definition=_SCORE_DEFINITION,
                group="wx",
                observation=obs,
            )
        )
