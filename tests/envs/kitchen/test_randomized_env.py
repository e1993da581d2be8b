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
    from d5rl.envs.kitchen.randomized.domain import SURFACES

    # the pattern pool is the same on every call (fixed seed) and its patterns differ
    images = [textures.pattern_image(n, 32) for n in textures.NAMES]
    assert np.array_equal(images[0], textures.pattern_image(textures.NAMES[0], 32))
    assert all(not np.array_equal(a, b) for a, b in zip(images, images[1:]))
    env.reset(seed=11)
    d = env.domain
    shots = {}
    for skin in ("plain", "checker", "wood"):
        env.set_domain(dataclasses.replace(d, textures=(skin,) * len(SURFACES)))
        shots[skin] = env.render_camera_image("left", 64, 64)
    assert np.abs(shots["plain"].astype(float) - shots["checker"]).mean() > 3.0
    assert np.abs(shots["checker"].astype(float) - shots["wood"]).mean() > 3.0
    # a renderer made after the switch draws the same image (textures are all uploaded up front)
    fresh = RandomizedKitchenEnv(image_size=64, domain=dataclasses.replace(d, textures=("wood",) * len(SURFACES)))
    fresh.reset(seed=0)
    fresh.set_state(env.get_state())
    assert np.array_equal(fresh.render_camera_image("left", 64, 64), shots["wood"])


def test_domain_from_an_older_version_is_refused():
    from d5rl.errors import D5RLError

    old = Domain.sample(np.random.default_rng(0)).to_json()
    old["colors"] = old["colors"][:4]
    del old["textures"]
    with pytest.raises(D5RLError, match="older version"):
        Domain.from_json(old)
