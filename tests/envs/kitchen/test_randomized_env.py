import functools

import numpy as np
import pytest

from d5rl.envs.kitchen.randomized.domain import Domain
from d5rl.envs.kitchen.randomized.task import RandomizedKitchenEnv


@pytest.fixture(scope="module")
def env():
    return RandomizedKitchenEnv(image_size=64)


def test_same_seed_same_images_different_seed_differs(env):
    a, ia = env.reset(seed=3)
    b, ib = env.reset(seed=3)
    c, ic = env.reset(seed=4)
    assert ia["domain"] == ib["domain"] != ic["domain"]
    for k in ("pixels/left", "pixels/right"):
        assert np.array_equal(a[k], b[k])
        assert np.abs(a[k].astype(float).mean((0, 1)) - c[k].astype(float).mean((0, 1))).max() > 1.0


def test_rerender_from_state_and_domain(env):
    obs, info = env.reset(seed=5)
    for _ in range(3):
        obs, *_ = env.step(env.action_space.sample() * 0 + 0.3)
    state = env.get_state()
    other = RandomizedKitchenEnv(image_size=64)
    other.reset(seed=0)
    other.set_domain(Domain.from_json(info["domain"]))
    other.set_state(state)
    for c in ("left", "right", "wrist"):
        assert np.array_equal(other.render_camera_image(c, 64, 64), obs[f"pixels/{c}"])


def test_env_checker_and_registration():
    from gymnasium.utils.env_checker import check_env

    from d5rl.registry import make_env

    env = make_env("kitchen-randomized-mixed-v0", image_size=32)
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=0)
    assert set(obs) == {"pixels/left", "pixels/right", "pixels/wrist", "proprio"} and "domain" in info


def test_surface_textures_show_and_switch_without_recompiling(env):
    import dataclasses

    from d5rl.envs.kitchen.randomized import textures
    from d5rl.envs.kitchen.randomized.domain import SKINS, SURFACES

    # the photographs load the same on every call, and the two scales differ (the 2x one is a tiling)
    wood1, wood2 = textures.photo_image("wood", 1, 64), textures.photo_image("wood", 2, 64)
    assert wood1.shape == (64, 64, 3) and not np.array_equal(wood1, wood2)
    np.testing.assert_array_equal(wood2[:32, :32], wood2[32:, 32:])
    assert wood1.std() > 5.0  # a photograph, not a flat colour
    env.reset(seed=11)
    d = env.domain

    def with_skin(skin):
        skins = tuple(skin if skin in SKINS[g] else SKINS[g][0] for g in SURFACES)
        return dataclasses.replace(d, textures=skins, colors=((1.0, 1.0, 1.0, 1.0),) * len(SURFACES))

    shots = {}
    for skin in ("plain", "wood@1", "tile@1"):
        env.set_domain(with_skin(skin))
        shots[skin] = env.render_camera_image("left", 64, 64)
    assert np.abs(shots["plain"].astype(float) - shots["wood@1"]).mean() > 3.0
    assert np.abs(shots["wood@1"].astype(float) - shots["tile@1"]).mean() > 3.0
    # a renderer made after the switch draws the same image (textures are all uploaded up front)
    fresh = RandomizedKitchenEnv(image_size=64, domain=with_skin("wood@1"))
    fresh.reset(seed=0)
    fresh.set_state(env.get_state())
    assert np.array_equal(fresh.render_camera_image("left", 64, 64), shots["wood@1"])


def test_every_object_model_has_its_own_collision_geometry_and_mass():
    import mujoco

    from d5rl.envs.kitchen.randomized import objects
    from d5rl.envs.kitchen.randomized.domain import compiled_variant

    compiled_variant = functools.lru_cache(compiled_variant)  # each (microwave, kettle) compiled once here

    def colliding(model, body):
        b = model.body(body).id
        rows = [
            (int(model.geom_type[g]), *np.round(model.geom_size[g], 4), *np.round(model.geom_pos[g], 4))
            for g in range(model.ngeom)
            if model.geom_bodyid[g] == b and model.geom_conaffinity[g]
        ]
        return sorted(rows), round(float(model.body_mass[b]), 4)

    kettles = [colliding(compiled_variant(0, k), "kettleroot") for k in range(objects.NUM_KETTLES)]
    for a in range(len(kettles)):
        for b in range(a + 1, len(kettles)):
            assert kettles[a][0] != kettles[b][0], (a, b)  # collision geometry differs
    assert len({m for _, m in kettles}) >= 7  # and the mass (two models may weigh the same)
    assert [m for _, m in kettles] == pytest.approx([k.mass for k in objects.KETTLES])
    doors = [colliding(compiled_variant(k, 0), "microdoorroot") for k in range(objects.NUM_MICROWAVES)]
    shells = [colliding(compiled_variant(k, 0), "microroot")[0] for k in range(objects.NUM_MICROWAVES)]
    for a in range(len(doors)):
        for b in range(a + 1, len(doors)):
            assert doors[a] != doors[b] and shells[a] != shells[b], (a, b)
    assert [m for _, m in doors] == pytest.approx([k.door_mass for k in objects.MICROWAVES])
    # the handle the operator aims at is the handle that collides: the site lies on a colliding bar
    for k in range(objects.NUM_KETTLES):
        m = compiled_variant(0, k)
        d = mujoco.MjData(m)
        mujoco.mj_forward(m, d)
        site = d.site_xpos[m.site("kettle_site").id]
        handle = [
            g
            for g in range(m.ngeom)
            if m.geom_bodyid[g] == m.body("kettleroot").id
            and m.geom_conaffinity[g]
            and m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE
        ]
        assert min(np.linalg.norm(d.geom_xpos[g] - site) for g in handle) < 1e-9, k


def test_high_quality_renders_shadows_with_the_same_physics():
    from d5rl.envs.kitchen.randomized.domain import Domain

    d = Domain.sample(np.random.default_rng(2))
    fast = RandomizedKitchenEnv(image_size=48, domain=d)
    high = RandomizedKitchenEnv(image_size=48, domain=d, quality="high")
    a, _ = fast.reset(seed=1)
    b, _ = high.reset(seed=1)
    for _ in range(3):
        act = np.full(9, 0.3, np.float32)
        a, *_ = fast.step(act)
        b, *_ = high.step(act)
    np.testing.assert_array_equal(fast.data.qpos, high.data.qpos)
    assert high.model.vis.quality.shadowsize > 0 and fast.model.vis.quality.shadowsize == 0
    assert np.abs(a["pixels/left"].astype(float) - b["pixels/left"]).mean() > 1.0
    with pytest.raises(Exception, match="quality"):
        RandomizedKitchenEnv(quality="ultra")


def test_domain_from_an_older_version_is_refused():
    from d5rl.errors import D5RLError

    old = Domain.sample(np.random.default_rng(0)).to_json()
    old["colors"] = old["colors"][:4]
    del old["textures"]
    with pytest.raises(D5RLError, match="older version"):
        Domain.from_json(old)


def test_lights_are_switched_not_compiled_and_state_envs_keep_one_model():
    from d5rl.envs.kitchen.randomized.domain import MAX_EXTRA_LIGHTS

    env = RandomizedKitchenEnv(obs_mode="state")
    rng = np.random.default_rng(0)
    domains = [Domain.sample(rng) for _ in range(12)]
    assert len({d.num_lights for d in domains}) > 1
    for i, d in enumerate(domains):
        env.reset(seed=i, options={"domain": d})
        lights = [env.model.light_active[env.model.light(f"rand_light{j}").id] for j in range(MAX_EXTRA_LIGHTS)]
        assert lights == [j < d.num_lights for j in range(MAX_EXTRA_LIGHTS)]
    assert env._variants == {}  # an environment that never rendered holds only its current model


def _episode(seed: int, size: int = 32):
    env = RandomizedKitchenEnv(image_size=size)
    obs, info = env.reset(seed=seed)
    return obs, info["domain"], env.get_state()


def test_same_seed_same_pixels_in_a_reused_env_and_a_fresh_one():
    # Seeds 0 and 7 draw the same (microwave, kettle) variant with different surface textures, so the
    # second reset reuses the first one's renderers, whose GL context copied the material textures.
    reused = RandomizedKitchenEnv(image_size=32)
    _, first = reused.reset(seed=0)
    obs, info = reused.reset(seed=7)
    d0, d7 = Domain.from_json(first["domain"]), Domain.from_json(info["domain"])
    assert d0.key == d7.key and d0.textures != d7.textures
    fresh, fresh_domain, _ = _episode(7)
    assert fresh_domain == info["domain"]
    for c in ("left", "right", "wrist"):
        np.testing.assert_array_equal(obs[f"pixels/{c}"], fresh[f"pixels/{c}"])


def test_render_cache_frames_do_not_depend_on_the_episode_order(monkeypatch):
    """A render-cache worker keeps one env per process: the frames of an episode must not depend on the
    episodes it rendered before."""
    from d5rl.envs.kitchen.randomized import data as rd

    episodes = {s: _episode(s)[1:] for s in (0, 7)}

    def render(order):
        monkeypatch.setattr(rd, "_RENDER_ENV", {})
        return {
            s: rd.render_episode({"states": episodes[s][1][None]}, {"domain": episodes[s][0]}, size=32) for s in order
        }

    a, b = render((0, 7)), render((7, 0))
    for s in (0, 7):
        for key in a[s]:
            assert a[s][key].tobytes() == b[s][key].tobytes(), (s, key)
