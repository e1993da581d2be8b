"""IQL: Implicit Q-Learning (Kostrikov et al., 2021).

V is fit to an upper expectile of Q(s, a) over dataset actions, Q to
r + γ V(s'), and the policy by advantage-weighted regression
exp(β (Q − V)) · log π(a|s).  No action outside the dataset is ever queried.

Metrics: ``value/loss``, ``value/v``, ``critic/loss``, ``critic/q``,
``actor/loss``, ``actor/adv``, ``actor/weight``, ``actor/mse``.
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
    auto_actor_decay,
    copy_tree,
    make_train_state,
    nonpytree_field,
    obs_ndims,
    prepare_example,
)
from d5rl.agents.config import Config
from d5rl.agents.encoders import make_encoder
from d5rl.agents.networks import Critic, GaussianPolicy, ValueCritic, soft_update


def expectile_loss(diff, expectile: float):
    """|τ − 1(diff < 0)| · diff²: the asymmetric L2 loss whose minimiser is the τ-expectile."""
    weight = jnp.where(diff > 0, expectile, 1 - expectile)
    return weight * diff**2


class IQLLosses:
    """IQL's value and Q losses (IQL and IDQL): the agent has ``critic``, ``target_critic_params``,
    ``value`` and a config with ``expectile`` and ``discount``."""

    def value_loss(self, value_params, batch):
        """Expectile regression of V(s) onto min_i Q_target_i(s, a)."""
        q = self.critic.apply_fn({"params": self.target_critic_params}, batch["observations"], batch["actions"]).min(0)
        v = self.value.apply_fn({"params": value_params}, batch["observations"])
        loss = expectile_loss(q - v, self.config.expectile).mean()
        return loss, {"value/loss": loss, "value/v": v.mean()}

    def critic_loss(self, critic_params, batch):
        """Q(s, a) → r + γ·mask·V(s'), summed over the ensemble."""
        next_v = self.value.apply_fn({"params": self.value.params}, batch["next_observations"])
        target = batch["rewards"] + self.config.discount * batch["masks"] * next_v
        qs = self.critic.apply_fn({"params": critic_params}, batch["observations"], batch["actions"])
        loss = ((qs - target[None]) ** 2).mean(axis=1).sum()
        return loss, {"critic/loss": loss, "critic/q": qs.mean(), "critic/target_q": target.mean()}


def actor_schedule(config: Config):
    """The policy's lr: cosine decay to 0 over ``actor_decay_steps`` updates (IQL's reference
    implementation, offline runs), or constant when that is 0 or None."""
    steps = config.actor_decay_steps
    return optax.cosine_decay_schedule(config.actor_lr, int(steps)) if steps else config.actor_lr


class IQLAgent(IQLLosses, Agent):
    rng: Any
    actor: Any
    critic: Any
    target_critic_params: Any
    value: Any
    config: Config = nonpytree_field()
    obs_ndim: tuple = nonpytree_field()

    resolve_config = classmethod(auto_actor_decay)  # actor_decay_steps=None: decay over an offline-only run

    def actor_loss(self, actor_params, batch, key):
        q = self.critic.apply_fn({"params": self.target_critic_params}, batch["observations"], batch["actions"]).min(0)
        v = self.value.apply_fn({"params": self.value.params}, batch["observations"])
        adv = q - v
        weight = jnp.minimum(jnp.exp(adv * self.config.temperature), self.config.max_weight)
        weight = jax.lax.stop_gradient(weight)
        dist = self.actor.apply_fn({"params": actor_params}, batch["observations"], train=True, rngs={"dropout": key})
        loss = -(weight * dist.log_prob(batch["actions"])).mean()
        mse = ((dist.mode() - batch["actions"]) ** 2).sum(-1).mean()
        return loss, {"actor/loss": loss, "actor/adv": adv.mean(), "actor/weight": weight.mean(), "actor/mse": mse}

    def _update(self, batch):
        rng, aug_key, key = jax.random.split(self.rng, 3)
        batch = augment_batch(aug_key, batch, self.config)
        # Order of the original implementation: V, then π (with the new V), then Q, then the target.
        g, value_info = jax.grad(self.value_loss, has_aux=True)(self.value.params, batch)
        agent = self.replace(rng=rng, value=self.value.apply_gradients(grads=g))
        g, actor_info = jax.grad(agent.actor_loss, has_aux=True)(agent.actor.params, batch, key)
        agent = agent.replace(actor=agent.actor.apply_gradients(grads=g))
        g, critic_info = jax.grad(agent.critic_loss, has_aux=True)(agent.critic.params, batch)
        critic = agent.critic.apply_gradients(grads=g)
        target = soft_update(agent.target_critic_params, critic.params, self.config.tau)
        agent = agent.replace(critic=critic, target_critic_params=target)
        return agent, {**value_info, **actor_info, **critic_info}

    @classmethod
    def create(cls, seed: int, example_observations, example_actions, config: Config | None = None):
        config = get_config() if config is None else config
        ex_obs, ex_act = prepare_example(example_observations, example_actions)
        rng, k_a, k_c, k_v = jax.random.split(jax.random.PRNGKey(seed), 4)
        actor_def = GaussianPolicy(
            make_encoder(config),
            config.hidden_dims,
            ex_act.shape[-1],
            tanh_squash=False,
            log_std_min=config.log_std_min,
            log_std_max=config.log_std_max,
            state_dependent_std=config.state_dependent_std,
        )
        critic_def = Critic(make_encoder(config), config.hidden_dims, config.num_qs, config.critic_layer_norm)
        value_def = ValueCritic(make_encoder(config), config.hidden_dims, config.critic_layer_norm)
        actor = make_train_state(actor_def, k_a, (ex_obs,), actor_schedule(config))
        critic = make_train_state(critic_def, k_c, (ex_obs, ex_act), config.critic_lr)
        value = make_train_state(value_def, k_v, (ex_obs,), config.value_lr)
        return cls(
            rng=rng,
            actor=actor,
            critic=critic,
            target_critic_params=copy_tree(critic.params),
            value=value,
            config=config,
            obs_ndim=obs_ndims(ex_obs),
        )


def get_config() -> Config:
    return Config(
        agent_name="iql",  # name in d5rl.agents.AGENTS
        actor_lr=3e-4,  # policy Adam lr (IQL paper; D5RL pixels: 1e-4)
        # None: `d5rl train` decays over --offline-steps when there is no online phase and keeps it
        # constant when fine-tuning (as IQL's fine-tuning configs do)
        actor_decay_steps=None,  # cosine decay of the policy lr over this many updates (IQL); 0: constant
        critic_lr=3e-4,  # Q Adam lr (IQL paper and D5RL)
        value_lr=3e-4,  # V Adam lr (IQL paper and D5RL)
        hidden_dims=(256, 256),  # MLP widths of all networks (IQL paper)
        discount=0.99,  # γ
        tau=0.005,  # Polyak rate of the target Q
        expectile=0.7,  # τ of the value expectile (D5RL sweeps 0.5, 0.7, 0.9, 0.95)
        temperature=3.0,  # β, inverse temperature of the advantage weights (IQL locomotion: 3; kitchen: 0.5)
        max_weight=100.0,  # clip of exp(β·A) (IQL)
        num_qs=2,  # clipped double Q
        critic_layer_norm=False,  # LayerNorm in Q and V
        log_std_min=-5.0,  # clip of the policy's log-std (IQL)
        log_std_max=2.0,  # upper clip of the policy's log-std
        state_dependent_std=False,  # IQL learns one log-std vector
        batch_size=256,  # minibatch size (256 state, 64 pixels in D5RL)
        **ENCODER_DEFAULTS,
    )
