"""Toy task ids: ``toy-reach-v0`` (state) and ``toy-reach-pixels-v0`` (two 16x16 cameras + position)."""

from __future__ import annotations

from d5rl.registry import DatasetSpec, ScoreRef, TaskSpec, register

HORIZON = 25  # d5rl.envs.toy.task.HORIZON (not imported: registration stays light)
# reference_returns() in d5rl/production/toy/data.py; tests/production/toy checks these against it
SCORE = ScoreRef(
    random=6.585704803466797,
    expert=20.73187255859375,
    source="d5rl.production.toy.data.reference_returns(): 20 seeded episodes of each policy",
)

for suffix, pixels in (("", False), ("-pixels", True)):
    register(
        TaskSpec(
            id=f"toy-reach{suffix}-v0",
            entry_point="d5rl.envs.toy.task:ToyReachEnv",
            max_episode_steps=HORIZON,
            description="numpy toy: move a point to a goal" + (" (two 16x16 cameras + position)" if pixels else ""),
            env_kwargs={"pixels": pixels},
            dataset=DatasetSpec(
                name=f"toy-reach{suffix}",
                version=1,
                generator="d5rl.production.toy.data:ToyGenerator",
                num_episodes=200,
                episodes_per_shard=50,
                generator_kwargs={"pixels": pixels},
                numerics="portable",  # the same bytes as with native numerics on the machine class measured
                description="200 episodes acting like the expert (noise 0.3) w.p. 0.3 per step, else randomly",
            ),
            score=SCORE,
            score_definition="(return - random policy return) / (expert return - random policy return)",
            group="toy",
            observation="pixels" if pixels else "state",
        )
    )
