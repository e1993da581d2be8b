"""The one rollout loop: episodes, returns and the transitions observers see, in-process and in a vector env."""

import gymnasium as gym
import numpy as np
import pytest

from d5rl.rollout import STOP, rollout


class Countdown(gym.Env):
    """Episode length ``3 + seed % 4``; reward = the action times the step's index (from 1); success at step 2;
    terminates at its length when the seed is even, truncates when it is odd."""

    observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float64)
    action_space = gym.spaces.Box(-10, 10, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        seed = 0 if seed is None else seed  # a vector env's autoreset
        self.seed_, self.t, self.n = seed, 0, 3 + seed % 4
        return np.array([seed, 0.0]), {"start": seed}

    def step(self, action):
        self.t += 1
        end = self.t >= self.n
        info = {"success": self.t == 2, "score": float(self.seed_ * 10 + self.t)}
        return (
            np.array([self.seed_, self.t]),
            float(action[0]) * self.t,
            end and self.seed_ % 2 == 0,
            end and self.seed_ % 2 == 1,
            info,
        )


def expected(seed, action_of):
    """(return, length, terminated) computed without the loop: the action ``action_of(seed, t)`` at each step."""
    n = 3 + seed % 4
    return sum(action_of(seed, t) * (t + 1) for t in range(n)), n, seed % 2 == 0


def act_from_obs(observations, live, steps):
    """Action = seed + 0.5 * step, read from the observation; checks the steps the loop passes."""
    obs = np.stack(observations)
    assert np.array_equal(obs[:, 1], steps)
    return (obs[:, :1] + 0.5 * obs[:, 1:]).astype(np.float32)


@pytest.mark.parametrize("vector", [False, True])
def test_each_episode_runs_to_its_end_with_its_own_seed_and_actions(vector):
    seeds = [4, 1, 6]
    envs = gym.vector.SyncVectorEnv([Countdown] * 4) if vector else [Countdown() for _ in range(3)]
    resets, steps, seen_live = [], [], []

    def act(observations, live, t):
        seen_live.append(list(live))
        return act_from_obs(observations, live, t)

    episodes = rollout(
        envs, act, seeds, on_reset=lambda i, obs, info: resets.append((i, info["start"])), on_step=steps.append
    )
    for seed, ep in zip(seeds, episodes):
        ret, n, term = expected(seed, lambda s, t: np.float32(s + 0.5 * t))
        assert (ep.seed, ep.length, ep.terminated, ep.truncated) == (seed, n, term, not term)
        assert ep.ret == pytest.approx(ret, rel=1e-6) and ep.success
        assert ep.info["score"] == seed * 10 + n  # the last step's info
    assert resets == [(0, 4), (1, 1), (2, 6)]
    # lengths 3, 4, 5: every episode acts in the first 3 steps, then only those still running
    assert seen_live == [[0, 1, 2]] * 3 + [[1, 2], [2]]
    mine = [s for s in steps if s.episode == 1]
    assert [s.t for s in mine] == [0, 1, 2, 3] and [s.done for s in mine] == [False] * 3 + [True]
    assert all(np.array_equal(s.next_obs, [1, s.t + 1]) and np.array_equal(s.obs, [1, s.t]) for s in mine)


def test_max_steps_truncates_and_fewer_envs_than_episodes_is_refused():
    (ep,) = rollout([Countdown()], lambda o, live, t: np.ones((len(live), 1), np.float32), [6], max_steps=2)
    assert (ep.length, ep.terminated, ep.truncated, ep.ret) == (2, False, True, 1.0 + 2.0)
    with pytest.raises(ValueError, match="2 episodes need 2 envs"):
        rollout([Countdown()], act_from_obs, [0, 1])


@pytest.mark.parametrize("vector", [False, True])
def test_act_can_end_an_episode_before_stepping(vector):
    """A scripted policy's STOP ends its episode without a step; the other episodes run on as before."""
    seeds = [4, 1, 6]  # natural lengths 3, 4, 5; episode 1 stops before its step 2, episode 2 before its step 0
    stop_at = {1: 2, 2: 0}
    envs = gym.vector.SyncVectorEnv([Countdown] * 3) if vector else [Countdown() for _ in range(3)]
    steps = []

    def act(observations, live, t):
        actions = act_from_obs(observations, live, t)
        return [STOP if stop_at.get(int(i)) == int(k) else a for i, k, a in zip(live, t, actions)]

    episodes = rollout(envs, act, seeds, on_step=steps.append)
    lengths = [(ep.length, ep.terminated, ep.truncated) for ep in episodes]
    assert lengths == [(3, True, False), (2, False, True), (0, False, True)]
    ret4, _, _ = expected(4, lambda s, t: np.float32(s + 0.5 * t))
    assert episodes[0].ret == pytest.approx(ret4, rel=1e-6)
    assert episodes[1].ret == pytest.approx(1.0 * 1 + 1.5 * 2, rel=1e-6)  # actions 1, 1.5 at steps 1, 2
    assert episodes[1].info["score"] == 1 * 10 + 2 and episodes[1].success  # its last step's info
    assert (episodes[2].ret, episodes[2].info, episodes[2].success) == (0.0, {}, False)
    assert sorted((s.episode, s.t) for s in steps) == [(0, 0), (0, 1), (0, 2), (1, 0), (1, 1)]
    assert not any(s.done for s in steps if s.episode == 1)  # the stop is not a step: no transition ends it
