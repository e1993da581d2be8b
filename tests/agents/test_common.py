"""Shared agent pieces: config parsing, distributions, networks, augmentation, schedules."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from d5rl.agents import UnknownAgentError, get_agent
from d5rl.agents.augment import augment_observations, color_jitter, random_shift
from d5rl.agents.config import Config, ConfigError
from d5rl.agents.diffusion import cosine_beta_schedule
from d5rl.agents.encoders import ObsEncoder
from d5rl.agents.networks import Critic, Gaussian


def test_config_override_parses_by_default_type():
    c = Config(a=1, b=0.5, c=True, d=(256, 256), e="x", f=None)
    d = c.override(["a=3", "b=1e-4", "c=false", "d=32,16", "e=y", "f=0.25"])
    assert (d.a, d.b, d.c, d.d, d.e, d.f) == (3, 1e-4, False, (32, 16), "y", 0.25)
    assert c.a == 1  # immutable
    assert hash(c) == hash(Config(a=1, b=0.5, c=True, d=(256, 256), e="x", f=None))
    assert Config(d.to_dict()) == d


@pytest.mark.parametrize("bad", ["zzz=1", "a=notanint", "c=maybe", "novalue"])
def test_config_override_errors(bad):
    with pytest.raises(ConfigError) as e:
        Config(a=1, c=True).override([bad])
    assert e.value.hint


def test_unknown_agent():
    with pytest.raises(UnknownAgentError):
        get_agent("ppo")
    assert get_agent("TD3+BC")[0].__name__ == "TD3BCAgent"


def test_gaussian_log_prob_matches_densities():
    loc = jnp.array([[0.3, -0.2]])
    log_std = jnp.array([[-0.5, 0.1]])
    a = jnp.array([[0.1, 0.7]])
    plain = Gaussian(loc, log_std, tanh=False)
    # the reference density in plain numpy/float (a JAX array inside pytest.approx breaks on pytest 9.2)
    a_np, loc_np, std = np.asarray(a, np.float64), np.asarray(loc, np.float64), np.exp(np.asarray(log_std, np.float64))
    expected = float(np.sum(-0.5 * ((a_np - loc_np) / std) ** 2 - np.log(std) - 0.5 * math.log(2 * math.pi)))
    assert float(plain.log_prob(a)[0]) == pytest.approx(expected, rel=1e-5)
    squashed = Gaussian(loc, log_std, tanh=True)
    u = np.arctanh(a_np)
    expected_t = float(
        np.sum(-0.5 * ((u - loc_np) / std) ** 2 - np.log(std) - 0.5 * math.log(2 * math.pi) - np.log(1 - a_np**2))
    )
    assert float(squashed.log_prob(a)[0]) == pytest.approx(expected_t, rel=1e-4)
    # sample_and_log_prob agrees with log_prob of its own sample
    s, lp = squashed.sample_and_log_prob(jax.random.PRNGKey(0))
    assert float(lp[0]) == pytest.approx(float(squashed.log_prob(s)[0]), rel=1e-3)
    assert np.all(np.abs(np.asarray(s)) < 1)


def test_critic_ensemble_members_differ():
    critic = Critic(ObsEncoder(), (16, 16), num_qs=5, layer_norm=True)
    obs, act = jnp.ones((3, 4)), jnp.zeros((3, 2))
    params = critic.init(jax.random.PRNGKey(0), obs, act)
    q = critic.apply(params, obs, act)
    assert q.shape == (5, 3)
    assert len(np.unique(np.round(np.asarray(q[:, 0]), 6))) == 5


def test_obs_encoder_pixels_then_proprio():
    enc = ObsEncoder(channels=(4, 4, 4), latent_dim=10)
    obs = {
        "pixels/a": jnp.zeros((2, 16, 16, 9), jnp.uint8),
        "pixels/b": jnp.zeros((2, 16, 16, 9), jnp.uint8),
        "proprio": jnp.arange(6.0).reshape(2, 3),
    }
    params = enc.init(jax.random.PRNGKey(0), obs)
    h = enc.apply(params, obs)
    assert h.shape == (2, 13)
    np.testing.assert_allclose(np.asarray(h[:, -3:]), np.arange(6.0).reshape(2, 3))


def test_random_shift_translates_within_pad():
    img = np.zeros((8, 12, 12, 3), np.uint8)
    img[:, 6, 6] = 255
    out = np.asarray(random_shift(jax.random.PRNGKey(1), jnp.asarray(img), pad=4))
    assert out.shape == img.shape and out.dtype == np.uint8
    moved = []
    for i in range(8):
        ys, xs = np.nonzero(out[i, :, :, 0])
        assert len(ys) == 1 and abs(ys[0] - 6) <= 4 and abs(xs[0] - 6) <= 4
        moved.append((ys[0], xs[0]))
    assert len(set(moved)) > 1  # per-sample offsets
    same = np.asarray(random_shift(jax.random.PRNGKey(1), jnp.asarray(img), pad=4))
    np.testing.assert_array_equal(out, same)


def test_color_jitter_properties():
    rng = np.random.default_rng(0)
    img = jnp.asarray(rng.integers(0, 256, (4, 8, 8, 6)), jnp.uint8)
    same = color_jitter(jax.random.PRNGKey(0), img, p=0.0)
    assert np.max(np.abs(np.asarray(same, int) - np.asarray(img, int))) <= 1
    out = np.asarray(color_jitter(jax.random.PRNGKey(0), img, p=1.0))
    assert out.dtype == np.uint8 and out.shape == img.shape
    assert np.mean(np.abs(out.astype(int) - np.asarray(img, int))) > 1
    obs = {"pixels/x": img, "proprio": jnp.ones((4, 2))}
    aug = augment_observations(jax.random.PRNGKey(0), obs)
    np.testing.assert_array_equal(np.asarray(aug["proprio"]), 1.0)


def test_augment_observations_is_each_camera_shifted_and_jittered_with_its_own_key():
    """The jitter runs once over the cameras concatenated (for speed); per camera it must be exactly
    random_shift + color_jitter with that camera's keys, and a 4-channel camera is only shifted."""
    rng = np.random.default_rng(3)
    obs = {
        "pixels/a": jnp.asarray(rng.integers(0, 256, (5, 12, 12, 9)), jnp.uint8),
        "pixels/b": jnp.asarray(rng.integers(0, 256, (5, 12, 12, 6)), jnp.uint8),
        "pixels/depth": jnp.asarray(rng.integers(0, 256, (5, 12, 12, 4)), jnp.uint8),
    }
    key = jax.random.PRNGKey(7)
    aug = jax.jit(augment_observations)(key, obs)
    for i, k in enumerate(sorted(obs)):
        k1, k2 = jax.random.split(jax.random.fold_in(key, i))
        want = random_shift(k1, obs[k], 4)
        if want.shape[-1] % 3 == 0:
            want = color_jitter(k2, want)
        np.testing.assert_array_equal(np.asarray(aug[k]), np.asarray(want), err_msg=k)
    assert not np.array_equal(np.asarray(aug["pixels/a"]), np.asarray(obs["pixels/a"]))


def chained_color_jitter(key, imgs, brightness=0.2, contrast=0.2, saturation=0.2, hue=0.05, p=0.8):
    """The jitter written step by step (same random draws as ``color_jitter``), in numpy float64."""
    kb, kc, ks, kh, kp = jax.random.split(key, 5)
    b, h, w, c = imgs.shape
    fb, fc, fs = (
        np.asarray(jax.random.uniform(k, (b,), minval=1 - r, maxval=1 + r), np.float64)[:, None, None, None, None]
        for k, r in ((kb, brightness), (kc, contrast), (ks, saturation))
    )
    theta = np.asarray(jax.random.uniform(kh, (b,), minval=-hue, maxval=hue), np.float64) * 2 * np.pi
    apply = np.asarray(jax.random.uniform(kp, (b,)) < p)
    x = np.asarray(imgs, np.float64).reshape(b, h, w, c // 3, 3)
    luma = np.array([0.299, 0.587, 0.114])
    y = x * fb
    mean = (y @ luma).mean(axis=(1, 2), keepdims=True)[..., None]
    y = (y - mean) * fc + mean
    gray = (y @ luma)[..., None]
    y = (y - gray) * fs + gray
    to_yiq = np.array([[0.299, 0.587, 0.114], [0.596, -0.274, -0.322], [0.211, -0.523, 0.312]])
    for i in range(b):
        rot = np.array([[1, 0, 0], [0, np.cos(theta[i]), -np.sin(theta[i])], [0, np.sin(theta[i]), np.cos(theta[i])]])
        y[i] = y[i] @ (np.linalg.inv(to_yiq) @ rot @ to_yiq).T
    y = np.where(apply[:, None, None, None, None], y, x)
    return np.clip(np.round(y), 0, 255).astype(np.uint8).reshape(b, h, w, c)


def test_color_jitter_is_the_four_steps_in_order():
    rng = np.random.default_rng(1)
    img = jnp.asarray(rng.integers(0, 256, (16, 8, 8, 9)), jnp.uint8)
    for seed in range(3):
        key = jax.random.PRNGKey(seed)
        ours = np.asarray(color_jitter(key, img), int)
        ref = chained_color_jitter(key, img).astype(int)
        assert np.max(np.abs(ours - ref)) <= 1 and np.mean(ours != ref) < 0.01
        assert np.mean(ours != np.asarray(img, int)) > 0.5  # it did jitter


def test_cosine_schedule():
    betas = np.asarray(cosine_beta_schedule(20))
    assert betas.shape == (20,) and np.all(betas > 0) and np.all(betas <= 0.999)
    alpha_hat = np.cumprod(1 - betas)
    assert np.all(np.diff(alpha_hat) < 0) and alpha_hat[0] > 0.99 and alpha_hat[-1] < 1e-3
