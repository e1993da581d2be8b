"""A1 task ids."""

from __future__ import annotations

import json
from pathlib import Path

from d5rl.envs.a1.published import TRAIN, buffer_episodes
from d5rl.registry import DatasetSpec, ScoreRef, TaskSpec, register

ENTRY = "d5rl.envs.a1.task:A1Env"
ENTRY_V1 = "d5rl.envs.a1.v1:A1EnvV1"
SCORES_FILE = Path(__file__).with_name("scores.json")


def _scores() -> dict:
    return json.loads(SCORES_FILE.read_text()) if SCORES_FILE.exists() else {}


def _ref(task_id: str, scores: dict) -> ScoreRef | None:
    s = scores.get(task_id)
    if s is None:
        return None
    trained = f" ({s['expert_trained']})" if "expert_trained" in s else ""
    note = (
        f"'{s['expert_agent']}'{trained} runs {s['expert_speed']:.2f} m/s on average on this task"
        if "expert_speed" in s
        else ""
    )
    return ScoreRef(s["random"], s["expert"], s["source"], expert_note=note)


SPEED_AGENTS = ("speed-0.5", "speed-0.8", "speed-1.0")  # data agents (d5rl.production.a1.agents.AGENTS)
HIKING_AGENTS = ("heading",)
# the agents each task's expert reference is the best of: its data agents and the reference agents trained for it
SCORE_AGENTS = {
    "a1-walk-v0": SPEED_AGENTS + ("run-1.25",),
    "a1-run-v0": SPEED_AGENTS + ("run-1.25",),
    "a1-hiking-v0": HIKING_AGENTS + ("hiking",),
}

LOCOMOTION_DATA = DatasetSpec(
    name="a1-locomotion",
    version=1,  # each version's agents: CHANGELOG.md
    generator="d5rl.production.a1.data:ReplayBufferGenerator",
    num_episodes=buffer_episodes(SPEED_AGENTS),
    episodes_per_shard=8,
    generator_kwargs={"agents": SPEED_AGENTS},
    description="replay buffers of three SAC agents trained to track 0.5, 0.8 and 1.0 m/s "
    "(deterministic: 0.52, 0.82 and 0.88 m/s), "
    "first exploration to expert, replayed from committed policy snapshots",
)
HIKING_DATA = DatasetSpec(
    name="a1-hiking",
    version=1,  # each version's agent: CHANGELOG.md
    generator="d5rl.production.a1.data:ReplayBufferGenerator",
    num_episodes=buffer_episodes(HIKING_AGENTS),
    episodes_per_shard=8,
    generator_kwargs={"agents": HIKING_AGENTS},
    description="replay buffer of a direction-conditioned SAC agent on flat ground",
)

_scores_table = _scores()
for task_id, speed, dataset in (("a1-walk-v0", 0.75, LOCOMOTION_DATA), ("a1-run-v0", 1.25, LOCOMOTION_DATA)):
    register(
        TaskSpec(
            id=task_id,
            entry_point=ENTRY,
            max_episode_steps=400,
            env_kwargs={"target_speed": speed},
            description=f"Unitree A1 tracking {speed} m/s on flat ground (20 Hz PD position control)",
            dataset=dataset,
            relabel="d5rl.production.a1.data:relabel_speed",
            score=_ref(task_id, _scores_table),
            score_definition="(return - random policy return) / (expert return - random policy return); "
            "expert = the best of the data agents and the reference agent run-1.25 "
            "(trained on the run task), evaluated on this task (d5rl calibrate)",
            group="a1",
        )
    )
register(
    TaskSpec(
        id="a1-hiking-v0",
        entry_point=ENTRY,
        max_episode_steps=1000,
        env_kwargs={"target_speed": 0.75, "terrain": "course", "command": "waypoints"},
        description="Unitree A1 walking a generated hiking course (bumps, ramps, waypoints); data from flat ground",
        dataset=HIKING_DATA,
        relabel="d5rl.production.a1.data:relabel_hiking",
        score=_ref("a1-hiking-v0", _scores_table),
        score_definition="(return - random policy return) / (expert return - random policy return); "
        "expert = the best of the data agent 'heading' and the reference agent 'hiking' "
        "(trained on the course), evaluated on the course (d5rl calibrate)",
        group="a1",
    )
)

# v1: the release's action range, reward, start and hiking course (d5rl.envs.a1.v1).  Their datasets replay
# the v1 data agents, which must be trained and published first (d5rl.production.a1.experts).
SPEED_AGENTS_V1 = ("speed-0.5-v1", "speed-0.8-v1", "speed-1.0-v1")
HIKING_AGENTS_V1 = ("goals-mixed-v1",)
SCORE_AGENTS.update(
    {
        "a1-walk-v1": SPEED_AGENTS_V1 + ("run-1.25-v1",),
        "a1-run-v1": SPEED_AGENTS_V1 + ("run-1.25-v1",),
        "a1-hiking-v1": ("goals-mixed-v1", "goals-smooth-v1", "hiking-v1"),
    }
)
TRAIN_V1 = TRAIN + " (then `publish`; docs/datacards/a1.md, v1)"


def _unavailable(agents: tuple[str, ...]) -> str | None:
    if buffer_episodes(agents):
        return None
    return "the v1 A1 data agents are not published yet; train them: " + TRAIN_V1.format(agents=" ".join(agents))


# each episode's scene (floor, friction, mass, goals) is drawn at reset: replays rebuild it from the stored seed
REPLAY_V1 = "d5rl.production.a1.data:replay_env"


def _v1_data(name: str, agents: tuple[str, ...], description: str) -> DatasetSpec:
    """A v1 dataset: the replay buffers of ``agents``, available once they are published."""
    return DatasetSpec(
        name=name,
        version=1,
        generator="d5rl.production.a1.data:ReplayBufferGenerator",
        num_episodes=buffer_episodes(agents),
        episodes_per_shard=8,
        generator_kwargs={"agents": agents},
        description=description,
        unavailable=_unavailable(agents),
        numerics="portable",
        replay=REPLAY_V1,
    )


LOCOMOTION_DATA_V1 = _v1_data(
    "a1-v1-locomotion",
    SPEED_AGENTS_V1,
    "replay buffers of three SAC agents trained on the release's run task to track 0.5, 0.8 "
    "and 1.0 m/s, first exploration to expert, replayed from committed policy snapshots",
)
HIKING_DATA_V1 = _v1_data(
    "a1-v1-hiking",
    HIKING_AGENTS_V1,
    "replay buffer of a SAC agent running toward random goals (the release's RunToward: smooth and bumpy floors)",
)
# The other hiking data candidate, on the plane only (the paper: the hiking data show "flat terrain"); BC on
# the course on each decides which agent's buffer is a1-v1-hiking (docs/datacards/a1.md, v1).
HIKING_SMOOTH_AGENTS_V1 = ("goals-smooth-v1",)
HIKING_SMOOTH_DATA_V1 = _v1_data(
    "a1-v1-hiking-smooth",
    HIKING_SMOOTH_AGENTS_V1,
    "replay buffer of a SAC agent running toward random goals on the plane (the release's RunToward, smooth "
    "floor only)",
)
for task_id, speed in (("a1-walk-v1", 0.75), ("a1-run-v1", 1.25)):
    register(
        TaskSpec(
            id=task_id,
            entry_point=ENTRY_V1,
            max_episode_steps=400,
            env_kwargs={"task": "run", "target_speed": speed},
            description=f"Unitree A1 tracking {speed} m/s on flat ground, as the D5RL release defines it",
            dataset=LOCOMOTION_DATA_V1,
            relabel="d5rl.production.a1.data:relabel_speed",
            score=_ref(task_id, _scores_table),
            score_definition="(return - random policy return) / (expert return - random policy return)",
            group="a1",
        )
    )
register(
    TaskSpec(
        id="a1-hiking-v1",
        entry_point=ENTRY_V1,
        max_episode_steps=1000,
        env_kwargs={"task": "hiking", "target_speed": 1.0},
        description="Unitree A1 hiking the release's course (redrawn per episode) through four waypoints at 1 m/s",
        dataset=HIKING_DATA_V1,
        dataset_variants={"smooth": HIKING_SMOOTH_DATA_V1},  # a1-hiking-smooth-v1
        relabel="d5rl.production.a1.data:relabel_hiking",
        score=_ref("a1-hiking-v1", _scores_table),
        score_definition="(return - random policy return) / (expert return - random policy return)",
        group="a1",
    )
)
