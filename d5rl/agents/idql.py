"""IDQL: Implicit Diffusion Q-Learning (Hansen-Estruch et al., 2023).

An IQL critic (expectile V, Q → r + γV(s')) and a diffusion behaviour policy
(:mod:`d5rl.agents.ddpm_bc`), trained independently; as in the D5RL release, the
actor takes two steps (on the two halves of the batch) for every critic step.  To act, draw
``num_samples`` actions from the diffusion policy per observation and take the
one with the highest min-ensemble target Q (D5RL: N = 64, argmax).

Metrics: ``value/loss``, ``value/v``, ``critic/loss``, ``critic/q``,
``critic/target_q``, ``actor/loss``.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from d5rl.agents.augment import augment_batch
from d5rl.agents.common import (
    ENCODER_DEFAULTS,
    Agent,
    copy_tree,
    make_train_state,
    nonpytree_field,
    obs_ndims,
    prepare_example,
)
from d5rl.agents.config import Config, ConfigError
from d5rl.agents.ddpm_bc import DiffusionPolicy, ddpm_sample, diffusion_config, make_diffusion_actor
from d5rl.agents.encoders import make_encoder
from d5rl.agents.iql import IQLLosses
from d5rl.agents.networks import Critic, ValueCritic, soft_update


class IDQLAgent(DiffusionPolicy, IQLLosses, Agent):
    rng: Any
    actor: Any
    target_actor_params: Any
    critic: Any
    target_critic_params: Any
    value: Any
    config: Config = nonpytree_field()
    obs_ndim: tuple = nonpytree_field()

    version = 2  # 2: two actor steps per critic step, lr decay over the release's horizon (1: one step)

    def _update(self, batch):
        cfg = self.config
        rng, aug_key, *keys = jax.random.split(self.rng, 2 + cfg.actor_steps)
        batch = augment_batch(aug_key, batch, cfg)
        g, value_info = jax.grad(self.value_loss, has_aux=True)(self.value.params, batch)
        agent = self.replace(rng=rng, value=self.value.apply_gradients(grads=g))
        g, critic_info = jax.grad(agent.critic_loss, has_aux=True)(agent.critic.params, batch)
        critic = agent.critic.apply_gradients(grads=g)
        # The release's IDQL (pixel_idql_learner.py, update) takes actor_steps steps on as many equal parts of the
        # batch for each critic step, each followed by the EMA of the sampling weights.
        actor, ema = agent.actor, agent.target_actor_params
        size = batch["actions"].shape[0] // cfg.actor_steps
        for i, key in enumerate(keys):
            part = jax.tree_util.tree_map(lambda x: x[i * size : (i + 1) * size], batch)
            g, actor_info = jax.grad(agent.actor_loss, has_aux=True)(actor.params, part, key)
            actor = actor.apply_gradients(grads=g)
            ema = soft_update(ema, actor.params, cfg.actor_ema)
        agent = agent.replace(
            critic=critic,
            target_critic_params=soft_update(agent.target_critic_params, critic.params, cfg.tau),
            actor=actor,
            target_actor_params=ema,
        )
        return agent, {**value_info, **critic_info, **actor_info}

    def _act(self, obs, seed, temperature):
        cfg, n = self.config, self.config.num_samples
        p = self.target_actor_params
        feats = self.actor.apply_fn({"params": p}, obs, method="encode")
        b = feats.shape[0]
        feats = jnp.repeat(feats, n, axis=0)  # (B·N, F), N consecutive rows per observation
        actions = ddpm_sample(
            self.actor.apply_fn, p, feats, seed, cfg.action_dim, cfg.diffusion_steps, cfg.clip_sampler, temperature
        )
        q_feats = self.critic.apply_fn({"params": self.target_critic_params}, obs, method="encode")
        q_feats = jnp.repeat(q_feats, n, axis=0)
        q = self.critic.apply_fn({"params": self.target_critic_params}, q_feats, actions, method="head").min(0)
        best = jnp.argmax(q.reshape(b, n), axis=1)
        return actions.reshape(b, n, -1)[jnp.arange(b), best]

    @classmethod
    def create(cls, seed: int, example_observations, example_actions, config: Config | None = None):
        config = get_config() if config is None else config
        ex_obs, ex_act = prepare_example(example_observations, example_actions)
        config = config.replace(action_dim=int(ex_act.shape[-1]))
        if config.actor_steps < 1 or config.batch_size % config.actor_steps:
            raise ConfigError(
                f"idql: batch_size {config.batch_size} does not split into actor_steps "
                f"{config.actor_steps} equal parts",
                "pick a batch size divisible by actor_steps",
            )
        rng, k_a, k_c, k_v = jax.random.split(jax.random.PRNGKey(seed), 4)
        actor = make_diffusion_actor(config, k_a, ex_obs, ex_act)
        critic_def = Critic(make_encoder(config), config.critic_hidden_dims, config.num_qs, config.critic_layer_norm)
        value_def = ValueCritic(make_encoder(config), config.critic_hidden_dims, config.critic_layer_norm)
        critic = make_train_state(critic_def, k_c, (ex_obs, ex_act), config.critic_lr)
        value = make_train_state(value_def, k_v, (ex_obs,), config.value_lr)
        return cls(
            rng=rng,
            actor=actor,
            target_actor_params=copy_tree(actor.params),
            critic=critic,
            target_critic_params=copy_tree(critic.params),
            value=value,
            config=config,
            obs_ndim=obs_ndims(ex_obs),
        )


def get_config() -> Config:
    return Config(
        agent_name="idql",  # name in d5rl.agents.AGENTS
        critic_lr=3e-4,  # Q Adam lr (IQL / IDQL)
        value_lr=3e-4,  # V Adam lr (IQL / IDQL)
        critic_hidden_dims=(256, 256),  # MLP widths of Q and V (IDQL)
        discount=0.99,  # γ
        tau=0.005,  # Polyak rate of the target Q
        expectile=0.7,  # τ of the value expectile (IDQL: 0.7; D5RL sweeps IQL's τ)
        num_qs=2,  # clipped double Q
        critic_layer_norm=False,  # LayerNorm in Q and V
        num_samples=64,  # N actions drawn per observation, the argmax-Q one is taken (D5RL: 64)
        actor_steps=2,  # actor steps per critic step, each on its share of the batch (release pixel_idql_learner)
        batch_size=256,  # minibatch size (256 state, 64 pixels in D5RL)
        action_dim=None,  # set by create() from the example actions
        **diffusion_config(),
        **ENCODER_DEFAULTS,
    )
