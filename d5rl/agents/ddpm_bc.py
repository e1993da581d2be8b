"""DDPM+BC: a diffusion behaviour-cloning policy (the IDQL actor on its own).

The noise model is IDQL's LayerNorm MLP-ResNet conditioned on observation
features and learnable Fourier features of the step; D5RL swaps IDQL's
variance-preserving schedule for the cosine schedule (Nichol & Dhariwal 2021)
with T = 20.  Actions are drawn by the DDPM reverse process from an exponential
moving average of the weights, clipping to [-1, 1] after every step.

Metrics: ``actor/loss`` (ε-prediction MSE), ``actor/lr``.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import optax

from d5rl.agents.augment import augment_batch
from d5rl.agents.common import (
    ENCODER_DEFAULTS,
    Agent,
    copy_tree,
    make_train_state,
    nonpytree_field,
    obs_ndims,
    prepare_example,
    release_actor_decay,
)
from d5rl.agents.config import Config
from d5rl.agents.diffusion import DiffusionNoiseModel, cosine_beta_schedule
from d5rl.agents.encoders import make_encoder
from d5rl.agents.networks import soft_update


def schedule(num_steps: int):
    """(betas, alphas, alpha_hats) of the cosine schedule."""
    betas = cosine_beta_schedule(num_steps)
    alphas = 1.0 - betas
    return betas, alphas, jnp.cumprod(alphas)


def diffusion_loss(apply_fn, params, obs, actions, key, num_steps: int):
    """ε-prediction loss: noise the data actions to a random step t and predict the noise."""
    k_t, k_noise, k_drop = jax.random.split(key, 3)
    _, _, alpha_hats = schedule(num_steps)
    t = jax.random.randint(k_t, (actions.shape[0],), 0, num_steps)
    noise = jax.random.normal(k_noise, actions.shape)
    ah = alpha_hats[t][:, None]
    noisy = jnp.sqrt(ah) * actions + jnp.sqrt(1 - ah) * noise
    eps = apply_fn({"params": params}, obs, noisy, t[:, None].astype(jnp.float32), True, rngs={"dropout": k_drop})
    return ((eps - noise) ** 2).sum(-1).mean()


def ddpm_sample(
    apply_fn, params, features, key, action_dim: int, num_steps: int, clip: bool = True, temperature: float = 1.0
):
    """Reverse diffusion from N(0, I) for each row of ``features`` → actions (B, A)."""
    betas, alphas, alpha_hats = schedule(num_steps)
    k0, key = jax.random.split(key)
    x = jax.random.normal(k0, (features.shape[0], action_dim))

    def step(carry, t):
        x, key = carry
        key, kz = jax.random.split(key)
        tt = jnp.full((x.shape[0], 1), t, jnp.float32)
        eps = apply_fn({"params": params}, features, x, tt, method="denoise")
        x = (x - (1 - alphas[t]) / jnp.sqrt(1 - alpha_hats[t]) * eps) / jnp.sqrt(alphas[t])
        z = jax.random.normal(kz, x.shape)
        x = x + (t > 0) * jnp.sqrt(betas[t]) * temperature * z
        if clip:
            x = jnp.clip(x, -1.0, 1.0)
        return (x, key), None

    (x, _), _ = jax.lax.scan(step, (x, key), jnp.arange(num_steps - 1, -1, -1))
    return jnp.clip(x, -1.0, 1.0)


def make_diffusion_actor(config: Config, key, ex_obs, ex_act):
    model = DiffusionNoiseModel(
        make_encoder(config),
        ex_act.shape[-1],
        config.num_blocks,
        config.hidden_dim,
        config.time_dim,
        config.dropout_rate,
    )
    lr = config.actor_lr
    if config.actor_decay_steps:
        lr = optax.cosine_decay_schedule(config.actor_lr, config.actor_decay_steps)
    t = jnp.zeros((ex_act.shape[0], 1), jnp.float32)
    return make_train_state(model, key, (ex_obs, ex_act, t), lr)


def diffusion_config() -> dict:
    """Defaults shared by DDPM+BC and IDQL's actor."""
    return dict(
        actor_lr=3e-4,  # Adam lr of the noise model (IDQL; the release's kitchen, A1 and WidowX configs)
        actor_decay_steps=None,  # cosine-decay the lr to 0 over this many updates; None = the release's horizon
        # (release_actor_decay: offline + online updates, 500k + 500k in its scripts); 0 = constant
        diffusion_steps=20,  # T (D5RL: cosine schedule with T = 20)
        num_blocks=3,  # LN-ResNet residual blocks (IDQL)
        hidden_dim=256,  # LN-ResNet width (IDQL)
        time_dim=64,  # Fourier time features (IDQL)
        dropout_rate=0.1,  # dropout in the LN-ResNet blocks (IDQL)
        actor_ema=0.001,  # EMA rate of the sampling weights (IDQL actor_tau)
        clip_sampler=True,  # clip to [-1, 1] after every reverse step (IDQL)
    )


class DiffusionPolicy:
    """The diffusion actor's part of DDPM+BC and IDQL: its denoising loss, its lr schedule (a cosine over the
    release's horizon), and acting through ``_act(obs, seed, temperature)`` (sampling and evaluation both
    draw from the policy; evaluation at temperature 1)."""

    resolve_config = classmethod(release_actor_decay)  # actor_decay_steps=None: the release's decay horizon

    def actor_loss(self, actor_params, batch, key):
        loss = diffusion_loss(
            self.actor.apply_fn, actor_params, batch["observations"], batch["actions"], key, self.config.diffusion_steps
        )
        return loss, {"actor/loss": loss}

    @jax.jit
    def _sample(self, obs, seed, temperature=1.0):
        return self._act(obs, seed, temperature)

    @jax.jit
    def _eval(self, obs, seed):
        return self._act(obs, seed, 1.0)


class DDPMBCAgent(DiffusionPolicy, Agent):
    rng: Any
    actor: Any
    target_actor_params: Any
    config: Config = nonpytree_field()
    obs_ndim: tuple = nonpytree_field()

    version = 2  # 2: lr decay over the release's horizon (1: over an offline-only run, constant when fine-tuning)

    def _update(self, batch):
        rng, aug_key, key = jax.random.split(self.rng, 3)
        batch = augment_batch(aug_key, batch, self.config)
        g, info = jax.grad(self.actor_loss, has_aux=True)(self.actor.params, batch, key)
        actor = self.actor.apply_gradients(grads=g)
        ema = soft_update(self.target_actor_params, actor.params, self.config.actor_ema)
        return self.replace(rng=rng, actor=actor, target_actor_params=ema), info

    def _act(self, obs, seed, temperature):
        p = self.target_actor_params
        feats = self.actor.apply_fn({"params": p}, obs, method="encode")
        return ddpm_sample(
            self.actor.apply_fn,
            p,
            feats,
            seed,
            self.config.action_dim,
            self.config.diffusion_steps,
            self.config.clip_sampler,
            temperature,
        )

    @classmethod
    def create(cls, seed: int, example_observations, example_actions, config: Config | None = None):
        config = get_config() if config is None else config
        ex_obs, ex_act = prepare_example(example_observations, example_actions)
        config = config.replace(action_dim=int(ex_act.shape[-1]))
        rng, k_a = jax.random.split(jax.random.PRNGKey(seed))
        actor = make_diffusion_actor(config, k_a, ex_obs, ex_act)
        return cls(
            rng=rng, actor=actor, target_actor_params=copy_tree(actor.params), config=config, obs_ndim=obs_ndims(ex_obs)
        )


def get_config() -> Config:
    return Config(
        agent_name="ddpm_bc",  # name in d5rl.agents.AGENTS
        batch_size=256,  # minibatch size (256 state, 64 pixels in D5RL)
        action_dim=None,  # set by create() from the example actions
        **diffusion_config(),
        **ENCODER_DEFAULTS,
    )
