"""Standard kitchen env: API checks, spaces, determinism, subtask success tests, rendering."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import d5rl
from d5rl.envs.kitchen import model as km
from d5rl.envs.kitchen.subtasks import MIXED, PARTIAL, SUBTASK_NAMES, SUBTASKS, CompletionChecker
from d5rl.envs.kitchen.task import KitchenEnv
from d5rl.envs.wrappers import FrameStack
from d5rl.errors import D5RLError

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def state_env():
    env = KitchenEnv(obs_mode="state")
    yield env
    env.close()


def _set_goal(env: KitchenEnv, name: str) -> None:
    sub = SUBTASKS[name]
    qpos = env.data.qpos.copy()
    qpos[sub.qpos_indices(env.model)] = sub.goal
    env.data.qpos[:] = qpos
    mujoco.mj_forward(env.model, env.data)


@pytest.mark.parametrize("obs_mode", ["state", "pixels"])
def test_check_env(obs_mode):
    env = KitchenEnv(obs_mode=obs_mode)
    check_env(env, skip_render_check=True)
    env.close()


def test_registered_tasks_and_spaces():
    assert {"kitchen-standard-mixed-v0", "kitchen-standard-partial-v0"} <= set(d5rl.list_tasks("kitchen"))
    env = d5rl.make_env("kitchen-standard-partial-v0")
    assert env.unwrapped.tasks == PARTIAL
    assert env.spec is None or env.spec.max_episode_steps in (None, 280)
    obs, info = env.reset(seed=0)
    assert set(obs) == {"pixels/overview", "pixels/wrist", "proprio"}
    assert obs["pixels/overview"].shape == (64, 64, 3) and obs["pixels/overview"].dtype == np.uint8
    assert obs["proprio"].shape == (9,)
    assert env.observation_space.contains(obs)
    assert env.action_space.shape == (9,) and env.action_space.low.min() == -1 and env.action_space.high.max() == 1
    assert env.unwrapped.dt == pytest.approx(0.08)
    big = KitchenEnv(image_size=128)
    assert big.reset(seed=0)[0]["pixels/wrist"].shape == (128, 128, 3)
    # 280 steps then truncation
    steps, truncated = 0, False
    env = d5rl.make_env("kitchen-standard-mixed-v0", obs_mode="state")
    env.reset(seed=0)
    while not truncated:
        _, _, terminated, truncated, _ = env.step(np.zeros(9, np.float32))
        assert not terminated
        steps += 1
    assert steps == 280


def test_bad_arguments_raise_d5rl_errors():
    with pytest.raises(D5RLError):
        KitchenEnv(tasks=("toaster",))
    with pytest.raises(D5RLError):
        KitchenEnv(obs_mode="rgbd")


def test_same_seed_same_bytes():
    def rollout(seed):
        env = KitchenEnv()
        rng = np.random.default_rng(seed)
        obs, _ = env.reset(seed=seed)
        out = [obs["pixels/overview"].tobytes(), env.get_state().tobytes()]
        for _ in range(10):
            obs, r, *_ = env.step(rng.uniform(-1, 1, 9).astype(np.float32))
            out += [obs["pixels/wrist"].tobytes(), env.get_state().tobytes(), np.float64(r).tobytes()]
        return out

    a, b, c = rollout(3), rollout(3), rollout(4)
    assert a == b
    assert a != c


def test_start_state_has_no_subtask_done(state_env):
    for seed in range(3):
        _, info = state_env.reset(seed=seed)
        assert not info["completed"].any()


@pytest.mark.parametrize("name", SUBTASK_NAMES)
def test_subtask_success_fires_at_goal_only(state_env, name):
    state_env.reset(seed=0)
    col = SUBTASK_NAMES.index(name)
    assert not state_env.completed()[col]
    _set_goal(state_env, name)
    done = state_env.completed()
    assert done[col]
    assert done.sum() == 1  # no other subtask fires
    # just outside the threshold it does not count
    sub = SUBTASKS[name]
    idx = sub.qpos_indices(state_env.model)
    qpos = state_env.data.qpos.copy()
    qpos[idx[0]] = sub.goal[0] + 0.31 * (1 if sub.goal[0] < 0 else -1)
    assert not CompletionChecker(state_env.model).completed(qpos)[col]


def test_reward_counts_target_objects_in_goal():
    env = KitchenEnv(obs_mode="state", tasks=MIXED)
    env.reset(seed=0)
    for k, name in enumerate(MIXED, start=1):
        _set_goal(env, name)
        qpos = env.data.qpos.copy()
        env.data.qvel[:] = 0
        # hold the objects there for a step: the reward is read after the step
        _, r, _, _, info = env.step(np.zeros(9, np.float32))
        env.data.qpos[:] = qpos
        mujoco.mj_forward(env.model, env.data)
        assert r == pytest.approx(k, abs=1) and info["score"] >= (k - 1) / 4
    _, r, _, _, info = env.step(np.zeros(9, np.float32))
    assert info["solved"].all() and info["score"] == 1.0 and info["success"]
    _set_goal(env, "top burner")  # not a target of the mixed task
    _, r2, *_ = env.step(np.zeros(9, np.float32))
    assert r2 <= 4


def test_episode_stats_record_every_subtask_ever_done():
    """info["episode_stats"]: each of the seven subtasks, 1.0 once its object was at its goal in this episode,
    whether the task counts it or not, and still 1.0 after the object leaves the goal."""
    env = KitchenEnv(obs_mode="state", tasks=MIXED)
    _, info = env.reset(seed=0)
    assert info["episode_stats"] == {f"subtask/{n.replace(' ', '_')}": 0.0 for n in SUBTASK_NAMES}
    start = env.data.qpos.copy()
    _set_goal(env, "top burner")  # not a target of the mixed task
    _, r, _, _, info = env.step(np.zeros(9, np.float32))
    assert r == 0 and info["score"] == 0 and info["episode_stats"]["subtask/top_burner"] == 1.0
    env.data.qpos[:] = start  # back to the rest pose: no subtask is in its goal configuration now
    mujoco.mj_forward(env.model, env.data)
    _, _, _, _, info = env.step(np.zeros(9, np.float32))
    assert not info["completed"].any()
    assert info["episode_stats"]["subtask/top_burner"] == 1.0 and sum(info["episode_stats"].values()) == 1.0
    _, info = env.reset(seed=1)
    assert sum(info["episode_stats"].values()) == 0.0
    env.close()


def test_zero_action_holds_the_arm_still(state_env):
    state_env.reset(seed=1)
    q0 = state_env.data.qpos[:7].copy()
    for _ in range(25):
        state_env.step(np.zeros(9, np.float32))
    assert np.abs(state_env.data.qpos[:7] - q0).max() < 0.03


def test_frame_stack():
    env = FrameStack(KitchenEnv(), 3)
    obs, _ = env.reset(seed=0)
    assert obs["pixels/overview"].shape == (64, 64, 9) and obs["proprio"].shape == (9,)
    np.testing.assert_array_equal(obs["pixels/overview"][..., :3], obs["pixels/overview"][..., 6:])
    first = obs["pixels/wrist"][..., 6:].copy()
    for _ in range(2):
        obs, *_ = env.step(np.full(9, 0.8, np.float32))
    np.testing.assert_array_equal(obs["pixels/wrist"][..., :3], first)  # oldest frame = the reset frame
    assert env.observation_space.contains(obs)


def test_fast_render_keeps_physics_and_objects_visible():
    fast, stock = km.build_model(), km.stock_model()
    for field in ("body_mass", "body_inertia", "body_ipos", "dof_damping", "actuator_gainprm", "opt_timestep"):
        np.testing.assert_array_equal(
            getattr(fast, field, None) if field != "opt_timestep" else fast.opt.timestep,
            getattr(stock, field, None) if field != "opt_timestep" else stock.opt.timestep,
        )
    colliding = (fast.geom_contype | fast.geom_conaffinity) > 0
    np.testing.assert_array_equal(fast.geom_size[colliding], stock.geom_size[colliding])
    np.testing.assert_array_equal(fast.geom_pos[colliding], stock.geom_pos[colliding])
    assert fast.mesh_facenum.sum() < 0.25 * stock.mesh_facenum.sum()
    env = KitchenEnv(obs_mode="pixels")
    env.reset(seed=0)
    before = {s: env.render_cameras(s)["overview"].astype(int) for s in (64, 128)}
    # every object that a subtask moves changes the overview image when it moves (the knobs are
    # small: a few pixels at 64x64)
    need = {
        "microwave": 40,
        "kettle": 20,
        "slide cabinet": 20,
        "hinge cabinet": 40,
        "light switch": 2,
        "bottom burner": 2,
        "top burner": 2,
    }
    for name, n in need.items():
        env.reset(seed=0)
        _set_goal(env, name)
        for s in (64, 128):
            after = env.render_cameras(s)["overview"].astype(int)
            changed = (np.abs(after - before[s]).sum(-1) > 30).sum()
            assert changed >= n * (s // 64) ** 2, f"{name}: only {changed} pixels change in the {s}px overview"
    assert before[64].std() > 20  # not a blank frame


def test_render_benchmark_runs():
    out = subprocess.run(
        [sys.executable, str(ROOT / "bench" / "kitchen_render.py"), "--frames", "5", "--stock-frames", "1"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )
    assert out.returncode == 0, out.stderr
    assert "overview" in out.stdout and "stock" in out.stdout
