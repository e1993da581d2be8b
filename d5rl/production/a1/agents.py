"""The A1 agents: what each is trained to do and what it is for.

Data agents' replay buffers are the A1 datasets; reference agents define score references.
Training: :mod:`d5rl.production.a1.experts`; their policies: :mod:`d5rl.envs.a1.published`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from d5rl.envs.a1 import rewards
from d5rl.envs.a1.published import POLICY_DIR, agent_log
from d5rl.envs.a1.task import A1Env
from d5rl.envs.a1.v1 import A1EnvV1

EPISODE_STEPS = 400


@dataclasses.dataclass(frozen=True)
class AgentSpec:
    """One agent: what it is trained to do and what it is for."""

    target_speed: float  # m/s
    command: str = "forward"  # A1Env command: forward | heading | waypoints
    terrain: str = "flat"  # A1Env terrain: flat | course
    role: str = "data"  # "data": its replay buffer is a dataset; "reference": defines a score reference only
    band: tuple[float, float] = (0.0, 0.03)  # full speed reward in [target + band[0], target + band[1]] m/s
    episode_steps: int = EPISODE_STEPS
    env_version: int = 0  # 0: d5rl.envs.a1.task.A1Env; 1: d5rl.envs.a1.v1.A1EnvV1 (the release's tasks)
    task: str = ""  # v1 only: A1EnvV1 task (run | run_toward | hiking)
    floors: str = "mixed"  # v1 run_toward only: "mixed" (smooth or bumpy per episode) or "smooth"

    @property
    def directed(self) -> bool:
        """Whether the agent follows a direction (heading, goals or waypoints) rather than running along +x."""
        return self.command != "forward" or self.task in ("run_toward", "hiking")

    @property
    def obs_dim(self) -> int:
        return 60 if self.directed else 58


AGENTS = {
    # the data-collecting agents of a1-locomotion (walk / run) and a1-hiking, as in the paper
    "speed-0.5": AgentSpec(0.5),
    "speed-0.8": AgentSpec(0.8),
    "speed-1.0": AgentSpec(1.0),
    "heading": AgentSpec(0.75, "heading"),  # flat ground, a heading command that turns every 100 steps
    # score references only (not in any dataset)
    # a1-run-v0's: trained on the run task's own reward (~0.89 m/s, not 1.25: v0's action range, a third of
    # the release's, limits the gaits: data card, "How fast does v0's action range let the A1 go?")
    "run-1.25": AgentSpec(1.25, role="reference"),
    "hiking": AgentSpec(0.75, "waypoints", "course", role="reference", band=(-0.1, 0.1), episode_steps=1000),
    # the a1-*-v1 tasks (the release's action range, reward and hiking course): data agents ...
    "speed-0.5-v1": AgentSpec(0.5, env_version=1, task="run"),
    "speed-0.8-v1": AgentSpec(0.8, env_version=1, task="run"),
    "speed-1.0-v1": AgentSpec(1.0, env_version=1, task="run"),
    # hiking data candidates: the release's RunToward (goals within ±10 m) on its mixed floors, or on the
    # plane only (the paper: the hiking data show "flat terrain")
    "goals-mixed-v1": AgentSpec(1.0, env_version=1, task="run_toward", floors="mixed"),
    "goals-smooth-v1": AgentSpec(1.0, env_version=1, task="run_toward", floors="smooth"),
    # ... and score references
    "run-1.25-v1": AgentSpec(1.25, role="reference", env_version=1, task="run"),
    "hiking-v1": AgentSpec(1.0, role="reference", band=(-0.1, 0.1), episode_steps=1000, env_version=1, task="hiking"),
}


def describe(agent: str, policy_dir: Path = POLICY_DIR) -> str:
    """How an agent was made, from its spec and its training log: "SAC, 83,750 steps, tracking 0.8 m/s on flat ground"."""
    spec = AGENTS[agent]
    steps = agent_log(agent, str(policy_dir))["steps"]
    where = (
        "on the hiking course past its waypoints"
        if spec.terrain == "course" or spec.task == "hiking"
        else (
            "on flat ground, following a turning heading command"
            if spec.command == "heading"
            else f"toward random goals ({spec.floors} floors)"
            if spec.task == "run_toward"
            else "on flat ground"
        )
    )
    return f"SAC, {steps:,} steps, tracking {spec.target_speed} m/s {where}"


def make_env(agent: str, **kwargs):
    """The env ``agent`` trains and collects data in (``kwargs``: e.g. ``render_mode``)."""
    spec = AGENTS[agent]
    if spec.env_version == 1:
        extra = {"floors": spec.floors} if spec.task == "run_toward" else {}
        return A1EnvV1(task=spec.task, target_speed=spec.target_speed, **extra, **kwargs)
    return A1Env(target_speed=spec.target_speed, terrain=spec.terrain, command=spec.command, **kwargs)


def training_reward(spec: AgentSpec, info: dict) -> float:
    """The agent's training reward from the env's reward terms (the task reward with ``spec.band``)."""
    lo, hi = spec.target_speed + spec.band[0], spec.target_speed + spec.band[1]
    speed = rewards.tolerance(info["forward_speed"], lo, hi, spec.target_speed, "linear") * info["standing"]
    if not spec.directed:
        return float(rewards.SPEED_REWARD_SCALE * speed - rewards.ENERGY_COEF * info["energy"])
    return float(
        rewards.SPEED_REWARD_SCALE * speed * rewards.heading_term(info["heading_error"])
        - rewards.HIKING_ENERGY_COEF * info["energy"]
    )
