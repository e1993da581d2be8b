"""The a1-*-v1 tasks against the D5RL release's definitions (legged_mujoco/__init__.py, tasks/run.py,
arenas/), each value computed here independently of d5rl's reward code."""

import mujoco
import numpy as np
import pytest

import d5rl
from d5rl.envs.a1 import arenas
from d5rl.envs.a1.v1 import A1EnvV1, euler_xyz

NOMINAL = np.array([0.0, 0.9, -1.8] * 4)
OFFSET = np.array([0.2, 0.4, 0.4] * 4)  # the release's A1._QPOS_OFFSET
# the A1's joint ranges (hip, thigh, calf) in the release's a1.xml
JOINT_LO = np.array([-0.802851, -1.0472, -2.69653] * 4)
JOINT_HI = np.array([0.802851, 4.18879, -0.916298] * 4)


# --- an independent implementation of the release's reward ------------------------------------------------
def tol(x, lo, hi, margin, sigmoid, value_at_margin):
    """dm_control.utils.rewards.tolerance for one scalar, written out case by case."""
    if lo <= x <= hi:
        return 1.0
    d = (lo - x if x < lo else x - hi) / margin
    if sigmoid == "gaussian":
        scale = np.sqrt(-2 * np.log(value_at_margin))
        return float(np.exp(-0.5 * (d * scale) ** 2))
    if sigmoid == "linear":
        s = d * (1 - value_at_margin)
        return 1 - s if s < 1 else 0.0
    s = d * np.sqrt(1 - value_at_margin)  # quadratic
    return 1 - s * s if s < 1 else 0.0


def quat_to_mat(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def release_run_reward(qpos, qvel, torque, target):
    """SimpleRun.get_reward: velocimeter x, quat_to_euler ('XYZ'), product of joint tolerances, signed energy."""
    rot = quat_to_mat(qpos[3:7])
    v_local = rot.T @ qvel[:3]  # the velocimeter at the trunk's origin (free joint: world-frame velocity)
    pitch = np.arcsin(rot[0, 2])
    yaw = -np.arctan2(rot[0, 1], rot[0, 0])
    speed = v_local[0] * np.cos(pitch) * np.cos(yaw)
    bonus = 10 * tol(speed, target - 0.1, target + 0.1, target, "linear", 0.0)
    standing = tol(rot[2, 2], 0.9, np.inf, 0.9, "quadratic", 0.0)
    for q, lo, hi, m in zip(qpos[7:], NOMINAL - OFFSET, NOMINAL + OFFSET, OFFSET):
        standing *= tol(q, lo, hi, m, "gaussian", 0.5)
    return bonus * standing - 0.01 * np.sum(qvel[6:] * torque)


def quat(roll=0.0, pitch=0.0, yaw=0.0):
    """wxyz of R = Rx(roll) Ry(pitch) Rz(yaw)."""
    out = np.empty(4)
    parts = [np.array([np.cos(a / 2), *(np.sin(a / 2) * np.eye(3)[i])]) for i, a in enumerate((roll, pitch, yaw))]
    mujoco.mju_mulQuat(out, parts[0], parts[1])
    mujoco.mju_mulQuat(out, out, parts[2])
    return out


def _set(env, joints, lin_vel=(0.0, 0.0, 0.0), orientation=(0.0, 0.0, 0.0), joint_vel=None, targets=None):
    env.reset(seed=0)
    env.data.qpos[:3] = [0.0, 0.0, 0.3]
    env.data.qpos[3:7] = quat(*orientation)
    env.data.qpos[7:] = joints
    env.data.qvel[:] = 0.0
    env.data.qvel[:3] = lin_vel
    env.data.qvel[6:] = np.zeros(12) if joint_vel is None else joint_vel
    env.data.ctrl[:] = joints if targets is None else targets
    mujoco.mj_forward(env.model, env.data)


RNG = np.random.default_rng(7)
STATES = {  # name: (joints, trunk linear velocity, (roll, pitch, yaw), joint velocities, targets)
    "at target, nominal": (NOMINAL, (0.75, 0, 0), (0, 0, 0), None, None),
    "inside the joint bands": (
        NOMINAL + 0.9 * OFFSET * np.sign(RNG.normal(size=12)),
        (0.7, 0.1, 0),
        (0, 0, 0),
        None,
        None,
    ),
    "joints at the band edge": (NOMINAL + OFFSET, (0.8, 0, 0), (0, 0, 0), None, None),
    "joints at the margin": (NOMINAL - 2 * OFFSET * np.tile([1, 0, 1], 4), (0.75, 0, 0), (0, 0, 0), None, None),
    "joints beyond the margin": (NOMINAL + 3 * OFFSET * np.tile([0, 1, 0], 4), (0.75, 0, 0), (0, 0, 0), None, None),
    "speed at the band edge": (NOMINAL, (0.85, 0, 0), (0, 0, 0), None, None),
    "speed at the margin": (NOMINAL, (1.6, 0, 0), (0, 0, 0), None, None),
    "speed beyond the margin": (NOMINAL, (-0.2, 0, 0), (0, 0, 0), None, None),
    "pitched and turned": (NOMINAL, (0.6, 0.2, 0.1), (0.1, 0.3, 0.5), None, None),
    "upright at its edge": (NOMINAL, (0.75, 0, 0), (np.arccos(0.9), 0, 0), None, None),
    "tilted into the upright margin": (NOMINAL, (0.75, 0, 0), (0.2, 0.9, 0), None, None),
    "moving joints, clipped torques": (
        NOMINAL + 0.1,
        (0.75, 0, 0),
        (0, 0, 0),
        RNG.normal(0, 3, 12),
        NOMINAL + RNG.uniform(-1, 1, 12),
    ),
    "fallen on its side": (NOMINAL, (0.3, 0, 0), (np.pi / 2, 0, 0), RNG.normal(0, 2, 12), NOMINAL - 0.3),
}


@pytest.fixture(scope="module")
def walk():
    return A1EnvV1("run", target_speed=0.75)


@pytest.mark.parametrize("name", list(STATES))
def test_reward_is_the_releases_formula(walk, name):
    joints, lin_vel, orientation, joint_vel, targets = STATES[name]
    _set(walk, joints, lin_vel, orientation, joint_vel, targets)
    expected = release_run_reward(walk.data.qpos.copy(), walk.data.qvel.copy(), walk.data.actuator_force.copy(), 0.75)
    reward, terms = walk.reward_terms()
    assert reward == pytest.approx(expected, rel=1e-9, abs=1e-9)
    assert terms["energy"] == pytest.approx(np.sum(walk.data.qvel[6:] * walk.data.actuator_force), rel=1e-12)


def test_reward_states_cover_the_margins(walk):
    # the states above reach each factor's band, margin and beyond (so a changed margin or sigmoid shows)
    def standing(name):
        _set(walk, *STATES[name])
        return walk.reward_terms()[1]["standing"]

    assert standing("joints at the band edge") == pytest.approx(1.0)
    assert standing("joints at the margin") == pytest.approx(0.5**8)  # 8 joints at value_at_margin 0.5
    assert standing("joints beyond the margin") == pytest.approx(np.exp(-0.5 * 4 * 2 * np.log(2)) ** 4)
    assert standing("upright at its edge") == pytest.approx(1.0)
    assert 0 < standing("tilted into the upright margin") < 1
    assert standing("fallen on its side") == pytest.approx(0.0, abs=1e-12)
    _set(walk, NOMINAL, (1.6, 0, 0))
    assert walk.reward_terms()[0] == pytest.approx(0.0, abs=1e-9)  # speed term 0 at target + 0.1 + margin


def test_euler_angles_are_dm_controls_xyz():
    scipy_rot = pytest.importorskip("scipy.spatial.transform").Rotation
    for angles in [(0.1, 0.3, 0.5), (-0.7, 0.2, 2.5), (1.2, -0.9, -2.0)]:
        q = quat(*angles)
        expected = scipy_rot.from_quat([*q[1:], q[0]]).as_euler("XYZ")  # intrinsic x-y-z
        np.testing.assert_allclose(euler_xyz(q), expected, atol=1e-12)
        np.testing.assert_allclose(euler_xyz(q), angles, atol=1e-12)


def test_action_mapping_is_the_release_range_rescaled(walk):
    low = np.maximum(NOMINAL - 3.0 * OFFSET, JOINT_LO)  # ClipActionToRange: nominal ± 3 offsets within the joints
    high = np.minimum(NOMINAL + 3.0 * OFFSET, JOINT_HI)
    np.testing.assert_allclose(low[:3], [-0.6, -0.3, -2.69653])
    np.testing.assert_allclose(high[:3], [0.6, 2.1, -0.916298])
    for a, expected in ((-1.0, low), (0.0, (low + high) / 2), (1.0, high)):
        walk.reset(seed=0)
        walk.step(np.full(12, a, np.float32))
        np.testing.assert_allclose(walk.data.ctrl, expected, atol=1e-6)  # the PD targets of that step
    walk.reset(seed=0)
    walk.step(np.full(12, 5.0, np.float32))  # out of range: clipped to +1 first
    np.testing.assert_allclose(walk.data.ctrl, high, atol=1e-6)


def test_torque_is_the_clipped_pd_law(walk):
    joints = NOMINAL + RNG.uniform(-0.2, 0.2, 12)
    qd = RNG.normal(0, 2, 12)
    targets = walk.joint_targets(np.r_[RNG.uniform(-0.02, 0.02, 6), 1, -1, 1, -1, 1, -1])  # some saturate
    _set(walk, joints, joint_vel=qd, targets=targets)
    raw = 60.0 * (targets - joints) - 6.0 * qd
    assert (np.abs(raw) > 33.5).sum() >= 4 and (np.abs(raw) < 33.5).sum() >= 4
    np.testing.assert_allclose(walk.data.actuator_force, np.clip(raw, -33.5, 33.5), rtol=1e-9, atol=1e-9)


def test_physics_options_are_the_release_arenas(walk):
    # dm_control's composer arena: noslip_iterations 5, tolerance 0; the A1 model: elliptic cones, impratio 100
    opt = walk.model.opt
    assert (opt.noslip_iterations, opt.noslip_tolerance, opt.impratio) == (5, 0.0, 100.0)
    assert opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC and opt.timestep == 0.001
    assert opt.integrator == mujoco.mjtIntegrator.mjINT_EULER  # the kd term acts explicitly, as the release's PD


def test_start_is_the_lowest_free_height_on_the_release_grid(walk):
    walk.reset(seed=0)
    z = walk.data.qpos[2]
    assert round((z - 0.125) / 0.01, 6).is_integer()
    np.testing.assert_allclose(walk.data.qpos[3:], [1, 0, 0, 0, *NOMINAL])
    assert walk.data.ncon == 0
    walk.data.qpos[2] -= 0.01
    mujoco.mj_forward(walk.model, walk.data)
    assert walk.data.ncon > 0


def test_random_actions_fall_quickly(walk):
    rng = np.random.default_rng(0)
    lengths = []
    for ep in range(3):
        walk.reset(seed=ep)
        for t in range(400):
            if walk.step(rng.uniform(-1, 1, 12))[2]:
                break
        lengths.append(t + 1)
    assert max(lengths) < 200  # v0's narrow range never fell in 400 steps


# --- hiking ---------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def hiking():
    return A1EnvV1("hiking")


def _at(env, x, y):
    env.data.qpos[:2] = [x, y]
    mujoco.mj_forward(env.model, env.data)
    env.task.after_step(env, env.np_random)
    return env.task.reached


def test_hiking_waypoints_count_within_01_m_in_2d(hiking):
    hiking.reset(seed=0)
    assert hiking.task.target(hiking).tolist() == [-10.0, 0.0]
    assert _at(hiking, -9.5, 0.5) == 0  # past the waypoint's x but 0.7 m away: not reached
    assert _at(hiking, -10.11, 0.0) == 0
    assert _at(hiking, -10.06, 0.06) == 1  # 0.085 m away
    assert hiking.task.target(hiking).tolist() == [0.0, 0.0]
    assert _at(hiking, 0.0, 0.099) == 2
    assert hiking.task.target(hiking).tolist() == [20.0, 0.0]
    hiking.data.qpos[1] = 3.1
    assert hiking.task.failed(hiking)


def test_hiking_course_is_redrawn_per_episode_and_fixed_per_seed(hiking):
    def field(seed):
        hiking.reset(seed=seed)
        return hiking.model.hfield_data.copy()

    a, b, c = field(5), field(5), field(6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    hiking.reset(seed=5)
    assert hiking.data.qpos[0] == -20.0 and hiking.target_speed == 1.0
    h = arenas.FIELD_ELEVATION * a.reshape(arenas.FIELD_RES, arenas.FIELD_RES) + arenas.FIELD_Z
    assert 0.35 < h.max() < 0.5  # the rim
    mid = arenas.FIELD_RES // 2
    assert h[mid, mid] < 0.06 and h[mid, 0] < 0.0  # low centre, edge under the plane
    # the wedges: crest 1.2 m at x = 12.25 and 26.25 (a ray from above hits it there)
    for x in (12.2, 26.3):
        dist = mujoco.mj_ray(
            hiking.model,
            hiking.data,
            np.array([x, 0.0, 5.0]),
            np.array([0.0, 0.0, -1.0]),
            None,
            1,
            -1,
            np.zeros(1, np.int32),
        )
        assert 5.0 - dist == pytest.approx(1.2, abs=0.02)


def test_hiking_reward_is_the_releases_runtoward_formula(hiking):
    hiking.reset(seed=0)
    _set(hiking, NOMINAL, (0.9, 0.3, 0.0), (0.05, 0.2, 0.4), RNG.normal(0, 1, 12), NOMINAL + 0.2)
    hiking.data.qpos[:2] = [-12.0, 1.0]
    mujoco.mj_forward(hiking.model, hiking.data)
    qpos, qvel, torque = hiking.data.qpos, hiking.data.qvel, hiking.data.actuator_force
    rot = quat_to_mat(qpos[3:7])
    speed = (rot.T @ qvel[:3])[0] * np.cos(np.arcsin(rot[0, 2]))
    delta = np.arctan2(0.0 - 1.0, -10.0 + 12.0) - np.arctan2(rot[1, 0], rot[0, 0])
    standing = tol(rot[2, 2], 0.9, np.inf, 0.9, "quadratic", 0.0)
    for q, lo, hi, m in zip(qpos[7:], NOMINAL - OFFSET, NOMINAL + OFFSET, OFFSET):
        standing *= tol(q, lo, hi, m, "gaussian", 0.5)
    expected = 10 * tol(speed, 0.9, 1.1, 1.0, "linear", 0) * tol(
        delta, -np.pi / 12, np.pi / 12, np.pi, "linear", 0
    ) * standing - 0.001 * np.sum(qvel[6:] * torque)
    assert hiking.reward_terms()[0] == pytest.approx(expected, rel=1e-9, abs=1e-9)


# --- the hiking data agent's task ----------------------------------------------------------------------------
def test_run_toward_draws_floor_friction_mass_and_goals():
    mixed, smooth = A1EnvV1("run_toward"), A1EnvV1("run_toward", floors="smooth")
    kinds = set()
    for seed in range(8):
        mixed.reset(seed=seed)
        bumpy = mixed.task.bumpy
        kinds.add(bumpy)
        assert (mixed.model.geom(arenas.FIELD).pos[2] == arenas.FIELD_Z) == bumpy
        assert mixed.data.qpos[2] > (0.4 if bumpy else 0.0)  # lowered onto the ~0.2 m field
        assert 0.75 <= mixed.model.geom("floor").friction[0] <= 1.25
        assert abs(mixed.model.body("trunk").mass[0] - 4.714) <= 0.25
        assert np.all(np.abs(mixed.task.goal) <= 10.0)
        smooth.reset(seed=seed)
        assert not smooth.task.bumpy and smooth.model.geom(arenas.FIELD).pos[2] < -5
    assert kinds == {True, False}
    goal = mixed.task.goal.copy()
    mixed.data.qpos[:2] = goal + [0.05, 0.0]
    mujoco.mj_forward(mixed.model, mixed.data)
    mixed.task.after_step(mixed, mixed.np_random)
    assert not np.array_equal(mixed.task.goal, goal)  # reached: a new goal


def test_hiking_renders_the_redrawn_course():
    env = d5rl.make_env("a1-hiking-v1", render_mode="rgb_array", render_size=(96, 128))
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (96, 128, 3) and frame.std() > 5
    env.close()


def test_v1_dataset_fails_first_with_one_line_until_its_agents_are_published():
    spec = d5rl.get_spec("a1-walk-v1")
    if spec.dataset.unavailable is None:
        pytest.skip("the v1 data agents are published")
    with pytest.raises(d5rl.D5RLError) as e:
        d5rl.make("a1-walk-v1")
    assert "\n" not in str(e.value) and "python -m d5rl.production.a1.experts train --agents speed-0.5-v1" in str(
        e.value
    )
    from d5rl.runner.cli import resolve_tasks

    assert "a1-walk-v1" not in resolve_tasks(["a1"]) and resolve_tasks(["a1-walk-v1"]) == ["a1-walk-v1"]


@pytest.mark.parametrize(
    "task,agent_env",
    [
        ("a1-walk-v1", ("run", {"target_speed": 0.5})),
        ("a1-run-v1", ("run", {"target_speed": 1.0})),
        ("a1-hiking-v1", ("run_toward", {})),
    ],
)
def test_relabelling_the_data_agents_infos_gives_the_tasks_reward(task, agent_env):
    """The v1 datasets store the data agents' reward terms; each task recomputes its reward from them."""
    from d5rl.production.a1 import data

    spec = d5rl.get_spec(task)
    relabel = getattr(data, spec.relabel.split(":")[1])

    def roll(env):
        env.reset(seed=1)
        rng = np.random.default_rng(1)
        infos, rewards = {k: [] for k in data.INFO_KEYS}, []
        for _ in range(40):
            _, r, term, _, info = env.step(rng.uniform(-0.5, 0.5, 12))
            rewards.append(r)
            for k in data.INFO_KEYS:
                infos[k].append(info[k])
            if term:
                break
        return {f"infos/{k}": np.asarray(v) for k, v in infos.items()}, np.asarray(rewards)

    own, own_rewards = roll(A1EnvV1(**spec.env_kwargs))  # on the task's own env: its rewards exactly
    np.testing.assert_allclose(relabel(spec, own)["rewards"], own_rewards, rtol=1e-6, atol=1e-4)
    infos, _ = roll(A1EnvV1(agent_env[0], **agent_env[1]))  # a data agent's env: the task's formula
    target = spec.env_kwargs["target_speed"]
    for i, r in enumerate(relabel(spec, infos)["rewards"]):
        fwd, standing, energy, err = (infos[f"infos/{k}"][i] for k in data.INFO_KEYS)
        speed = tol(fwd, target - 0.1, target + 0.1, target, "linear", 0.0)
        if task == "a1-hiking-v1":
            want = 10 * speed * tol(err, -np.pi / 12, np.pi / 12, np.pi, "linear", 0.0) * standing - 0.001 * energy
        else:
            want = 10 * speed * standing - 0.01 * energy
        assert r == pytest.approx(want, rel=1e-5, abs=1e-4)
