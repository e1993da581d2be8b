"""What the A1 family publishes next to its code, read without MuJoCo or JAX: the data agents' policies
(``policies/<agent>/``: snapshots, final policy and the training log saying which snapshot collected how
many episodes), which the A1 datasets replay.  :mod:`d5rl.production.a1` trains and publishes them;
registration reads the datasets' sizes from their logs.

``$D5RL_A1_POLICIES/<agent>/`` replaces ``policies/<agent>/`` when that variable is set (read at import;
worker processes inherit it): datasets, calibration and checks then use those policies, e.g. trained ones
before they are published.
"""

from __future__ import annotations

import functools
import json
import os
from pathlib import Path

from d5rl.errors import D5RLError

POLICY_DIR = Path(os.environ.get("D5RL_A1_POLICIES") or Path(__file__).with_name("policies"))
TRAIN = "python -m d5rl.production.a1.experts train --agents {agents}"


@functools.cache
def agent_log(agent: str, policy_dir: str = str(POLICY_DIR)) -> dict:
    """``policies/<agent>/log.json``: the agent's training steps and, per snapshot segment, its episodes."""
    path = Path(policy_dir) / agent / "log.json"
    if not path.exists():
        raise D5RLError(
            f"the A1 data-collecting agent {agent!r} has no policy snapshots ({path} is missing)",
            f"train it: `{TRAIN.format(agents=agent)}` (needs the `train` extra)",
        )
    return json.loads(path.read_text())


def buffer_episodes(agents: tuple[str, ...]) -> int:
    """How many episodes the agents' replay buffers hold together (0 while one of them is unpublished)."""
    try:
        return sum(int(seg["episodes"]) for agent in agents for seg in agent_log(agent)["segments"])
    except D5RLError:
        return 0
