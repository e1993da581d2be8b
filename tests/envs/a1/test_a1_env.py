import mujoco
import numpy as np
import pytest

import d5rl
from d5rl.envs.a1 import rewards
from d5rl.envs.a1.model import NOMINAL_POSE, Course

TASKS = ["a1-walk-v0", "a1-run-v0", "a1-hiking-v0"]


@pytest.mark.parametrize("task", TASKS)
def test_render(task):
    env = d5rl.make_env(task, render_mode="rgb_array", render_size=(96, 128))
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (96, 128, 3) and frame.dtype == np.uint8
    assert frame.std() > 5  # not a blank image
    env.close()


def test_stands_five_seconds_under_zero_action():
    env = d5rl.make_env("a1-walk-v0")
    env.reset(seed=0)
    base = env.unwrapped
    for _ in range(100):  # 100 x 0.05 s
        _, _, term, _, _ = env.step(np.zeros(12, np.float32))
        assert not term
    assert base.data.qpos[2] > 0.22  # trunk height: still standing (nominal ~0.25-0.27)
    assert base.upright() > 0.98
    np.testing.assert_allclose(base.joint_pos(), NOMINAL_POSE, atol=0.15)
    assert np.linalg.norm(base.data.qpos[:2]) < 0.15  # did not wander


def _reward_at_speed(task, speed):
    env = d5rl.make_env(task)
    env.reset(seed=0)
    base = env.unwrapped
    mujoco.mj_resetDataKeyframe(base.model, base.data, base.model.key("home").id)
    base.data.qvel[0] = speed  # trunk moving forward (body x = world x at yaw 0), joints still
    mujoco.mj_forward(base.model, base.data)
    reward, terms = base.reward_terms()
    return reward, terms


@pytest.mark.parametrize("task,target", [("a1-walk-v0", 0.75), ("a1-run-v0", 1.25)])
def test_reward_high_at_target_speed_low_standing_still(task, target):
    r_track, terms = _reward_at_speed(task, target)
    assert terms["forward_speed"] == pytest.approx(target, abs=1e-6)
    assert r_track > 0.95 * rewards.SPEED_REWARD_SCALE
    r_still, _ = _reward_at_speed(task, 0.0)
    assert r_still < 0.25 * rewards.SPEED_REWARD_SCALE
    r_double, _ = _reward_at_speed(task, 2 * target + 0.2)
    assert r_double < 0.1 * rewards.SPEED_REWARD_SCALE


def test_tipping_over_terminates():
    env = d5rl.make_env("a1-walk-v0")
    env.reset(seed=0)
    base = env.unwrapped
    base.data.qpos[3:7] = [np.cos(np.pi / 4), np.sin(np.pi / 4), 0, 0]  # rolled 90 degrees
    base.data.qpos[2] = 0.4
    mujoco.mj_forward(base.model, base.data)
    _, _, term, _, info = env.step(np.zeros(12, np.float32))
    assert term and info["episode_stats"]["ended_early"] == 1.0


def test_episode_stats_mean_forward_speed_and_waypoints():
    """info["episode_stats"]: the mean of the steps' forward speeds so far, and on the course the waypoints passed."""
    env = d5rl.make_env("a1-walk-v0")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    speeds = []
    for _ in range(30):
        _, _, term, _, info = env.step(rng.uniform(-1, 1, 12).astype(np.float32))
        speeds.append(info["forward_speed"])
    assert info["episode_stats"]["forward_speed"] == pytest.approx(np.mean(speeds), abs=1e-12)
    assert info["episode_stats"]["ended_early"] == float(term) and "waypoints_reached" not in info["episode_stats"]
    env.reset(seed=1)
    _, _, _, _, info = env.step(np.zeros(12, np.float32))
    assert info["episode_stats"]["forward_speed"] == pytest.approx(info["forward_speed"], abs=1e-12)  # reset clears it
    hike = d5rl.make_env("a1-hiking-v0")
    hike.reset(seed=0)
    hike.unwrapped.data.qpos[0] = 0.5  # past the waypoints at x = -10 and 0
    _, _, _, _, info = hike.step(np.zeros(12, np.float32))
    assert info["episode_stats"]["waypoints_reached"] == 2.0


def test_hiking_course_is_rough_and_deterministic():
    h = Course(seed=0).heights()
    assert np.array_equal(h, Course(seed=0).heights())
    assert not np.array_equal(h, Course(seed=1).heights())
    assert h.max() - h.min() > 0.5  # ramps
    bumps = h - h.mean(axis=0, keepdims=True)
    assert bumps.std() > 0.02  # rolling bumps across the course
    env = d5rl.make_env("a1-hiking-v0")
    obs, _ = env.reset(seed=0)
    assert obs.shape == (60,)
    assert abs(env.unwrapped.data.qpos[0] - (-20.0)) < 1e-6


def test_hiking_lateral_offset_terminates():
    env = d5rl.make_env("a1-hiking-v0")
    env.reset(seed=0)
    env.unwrapped.data.qpos[1] = 3.5
    _, _, term, _, _ = env.step(np.zeros(12, np.float32))
    assert term


def test_state_round_trip_replays_exactly():
    env = d5rl.make_env("a1-walk-v0")
    env.reset(seed=1)
    base = env.unwrapped
    rng = np.random.default_rng(0)
    for _ in range(5):
        env.step(rng.uniform(-1, 1, 12).astype(np.float32))
    s = base.get_state()
    a = rng.uniform(-1, 1, 12).astype(np.float32)
    o1 = env.step(a)[0]
    base.set_state(s)
    o2 = env.step(a)[0]
    np.testing.assert_array_equal(o1[:-12], o2[:-12])  # previous-action part is env bookkeeping
