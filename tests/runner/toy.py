"""A small but real job for runner tests: a numpy linear policy learns to reach a goal.

Tasks ``test-reachnear-v0`` / ``test-reachfar-v0``: a point in the plane starts at the
origin and should move to a task-specific goal; action = velocity in [-1, 1]²,
position += 0.1·action, reward = −distance, 20 steps.  The "algorithms" fit a
linear policy ``a = W·(goal − x)`` by gradient descent on noisy expert data
(``bc``: plain regression, ``iql``: advantage-weighted regression with a larger
step size), then keep training on their own noisy rollouts in the online phase.
Scores are normalized with the random and expert returns on the same eval seeds.

Failure injection through ``cell.overrides``: ``fail="always"`` raises,
``fail="once:<path>"`` raises on the first attempt only (a sentinel file marks it),
``fail="crash"`` kills the worker process; ``sleep`` (seconds) slows each evaluation.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

from d5rl.registry import ScoreRef, TaskSpec, register

GOALS = {"test-reachnear-v0": (0.4, 0.3), "test-reachfar-v0": (0.9, -0.8)}
HORIZON = 20
JOB = "tests.runner.toy:reach_job"


class ReachEnv(gym.Env):
    observation_space = gym.spaces.Box(-2, 2, (4,), np.float32)
    action_space = gym.spaces.Box(-1, 1, (2,), np.float32)

    def __init__(self, goal=(0.5, 0.5)):
        self.goal = np.asarray(goal, np.float64)
        self.x = np.zeros(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = self.np_random.uniform(-0.05, 0.05, 2)
        return self._obs(), {}

    def _obs(self):
        return np.concatenate([self.x, self.goal - self.x]).astype(np.float32)

    def step(self, action):
        self.x = self.x + 0.1 * np.clip(action, -1, 1)
        return self._obs(), -float(np.linalg.norm(self.goal - self.x)), False, False, {}


def register_tasks():
    for tid, goal in GOALS.items():
        register(
            TaskSpec(
                id=tid,
                entry_point="tests.runner.toy:ReachEnv",
                max_episode_steps=HORIZON,
                description="runner test task",
                env_kwargs={"goal": goal},
                score=ScoreRef(random=0.0, expert=1.0, source="normalized inside the job"),
            )
        )


register_tasks()


def _rollout(goal, policy, rng, episodes):
    rets = []
    for _ in range(episodes):
        x = rng.uniform(-0.05, 0.05, 2)
        ret = 0.0
        for _ in range(HORIZON):
            x = x + 0.1 * np.clip(policy(x, rng), -1, 1)
            ret -= float(np.linalg.norm(goal - x))
        rets.append(ret)
    return float(np.mean(rets))


def reach_job(cell, cell_dir: Path):
    over = dict(cell.overrides)
    fail = str(over.get("fail", ""))
    if fail == "always":
        raise RuntimeError(f"injected failure in {cell.key}")
    if fail.startswith("once:"):
        sentinel = Path(fail[5:])
        if not sentinel.exists():
            sentinel.write_text("failed once")
            raise RuntimeError(f"injected first-attempt failure in {cell.key}")
    if fail == "crash":
        os.kill(os.getpid(), signal.SIGKILL)
    sleep = float(over.get("sleep", 0.0))
    goal = np.asarray(GOALS[cell.task])
    lr = {"bc": 0.02, "iql": 0.05}.get(cell.algo, 0.01)
    eval_every = int(cell.protocol.get("eval_interval", max(1, cell.offline_steps // 4)))
    episodes = int(cell.protocol.get("eval_episodes", 5))
    rng = np.random.default_rng(cell.seed)
    # noisy expert demonstrations: a = clip((goal - x) / 0.1) + noise
    xs = rng.uniform(-1, 1, (256, 2))
    acts = np.clip((goal - xs) / 0.1, -1, 1) + 0.3 * rng.standard_normal((256, 2))
    feats = goal - xs
    W = 0.1 * rng.standard_normal((2, 2))
    (Path(cell_dir) / "config.json").write_text(
        json.dumps({"algo": cell.algo, "task": cell.task, "lr": lr, "seed": cell.seed, **over}, indent=2)
    )

    def score(W_):
        ev = np.random.default_rng(1000 + cell.seed)  # same eval starts for all three policies
        s = ev.bit_generator.state
        pol = _rollout(goal, lambda x, r: W_ @ (goal - x), ev, episodes)
        ev.bit_generator.state = s
        rnd = _rollout(goal, lambda x, r: r.uniform(-1, 1, 2), ev, episodes)
        ev.bit_generator.state = s
        exp = _rollout(goal, lambda x, r: np.clip((goal - x) / 0.1, -1, 1), ev, episodes)
        return (pol - rnd) / (exp - rnd), pol

    with open(Path(cell_dir) / "eval.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["step", "phase", "score", "return", "episodes"])
        total = cell.offline_steps + cell.online_steps
        for step in range(1, total + 1):
            phase = "offline" if step <= cell.offline_steps else "online"
            if phase == "online" and step % 8 == 1:  # collect own noisy data, add to the buffer
                new_x = rng.uniform(-1, 1, (16, 2))
                new_a = np.clip((goal - new_x) / 0.1, -1, 1) + 0.5 * rng.standard_normal((16, 2))
                feats = np.concatenate([feats, goal - new_x])
                acts = np.concatenate([acts, new_a])
            idx = rng.integers(0, len(feats), 32)
            pred = feats[idx] @ W.T
            grad = (pred - acts[idx]).T @ feats[idx] / len(idx)
            W = W - lr * grad
            if step % eval_every == 0 or step == cell.offline_steps or step == total:
                s, ret = score(W)
                w.writerow([step, phase, repr(s), repr(ret), episodes])
                f.flush()
                if sleep:
                    time.sleep(sleep)
    # a tiny "rollout video": frames of the point's position
    import imageio.v2 as imageio

    frames = []
    x = np.zeros(2)
    for _ in range(8):
        img = np.zeros((16, 16, 3), np.uint8)
        px, py = np.clip(((x + 1) / 2 * 15).round().astype(int), 0, 15)
        img[py, px] = 255
        frames.append(img)
        x = x + 0.1 * np.clip(W @ (goal - x), -1, 1)
    (Path(cell_dir) / "videos").mkdir(exist_ok=True)
    imageio.mimsave(Path(cell_dir) / "videos" / "final.gif", frames)
    return {"final_W": W.tolist()}
