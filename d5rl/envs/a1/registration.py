"""A1 task ids."""

from __future__ import annotations

import json
from pathlib import Path

from d5rl.envs.a1.buffers import num_episodes
from d5rl.registry import DatasetSpec, ScoreRef, TaskSpec, register

ENTRY = "d5rl.envs.a1.task:A1Env"
SCORES_FILE = Path(__file__).with_name("scores.json")


def _scores() -> dict:
    return json.loads(SCORES_FILE.read_text()) if SCORES_FILE.exists() else {}


def _ref(task_id: str, scores: dict) -> ScoreRef | None:
    s = scores.get(task_id)
    if s is None:
        return None
    note = (f"'{s['expert_agent']}' runs {s['expert_speed']:.2f} m/s on average on this task"
            if "expert_speed" in s else "")
    return ScoreRef(s["random"], s["expert"], s["source"], expert_note=note)


SPEED_AGENTS = ("speed-0.5", "speed-0.8", "speed-1.0")
HIKING_AGENTS = ("heading",)

LOCOMOTION_DATA = DatasetSpec(
    name="a1-locomotion",
    version=0,
    generator="d5rl.envs.a1.data:ReplayBufferGenerator",
    num_episodes=num_episodes(SPEED_AGENTS),
    episodes_per_shard=8,
    generator_kwargs={"agents": SPEED_AGENTS},
    description="replay buffers of three SAC agents trained to track 0.5, 0.8 and 1.0 m/s, "
                "first exploration to expert, replayed from committed policy snapshots",
)
HIKING_DATA = DatasetSpec(
    name="a1-hiking",
    version=0,
    generator="d5rl.envs.a1.data:ReplayBufferGenerator",
    num_episodes=num_episodes(HIKING_AGENTS),
    episodes_per_shard=8,
    generator_kwargs={"agents": HIKING_AGENTS},
    description="replay buffer of a direction-conditioned SAC agent on flat ground",
)

_scores_table = _scores()
for task_id, speed, dataset in (("a1-walk-v0", 0.75, LOCOMOTION_DATA), ("a1-run-v0", 1.25, LOCOMOTION_DATA)):
    register(TaskSpec(
        id=task_id,
        entry_point=ENTRY,
        max_episode_steps=400,
        env_kwargs={"target_speed": speed},
        description=f"Unitree A1 tracking {speed} m/s on flat ground (20 Hz PD position control)",
        dataset=dataset,
        relabel="d5rl.envs.a1.data:relabel_speed",
        score=_ref(task_id, _scores_table),
        score_definition="(return - random policy return) / (expert return - random policy return); "
                         "expert = the best data-collecting agent evaluated on this task (d5rl calibrate)",
        group="a1",
    ))
register(TaskSpec(
    id="a1-hiking-v0",
    entry_point=ENTRY,
    max_episode_steps=1000,
    env_kwargs={"target_speed": 0.75, "terrain": "course", "command": "waypoints"},
    description="Unitree A1 walking a generated hiking course (bumps, ramps, waypoints); data from flat ground",
    dataset=HIKING_DATA,
    relabel="d5rl.envs.a1.data:relabel_hiking",
    score=_ref("a1-hiking-v0", _scores_table),
    score_definition="(return - random policy return) / (expert return - random policy return); "
                     "expert = the heading agent evaluated on the course (d5rl calibrate)",
    group="a1",
))
