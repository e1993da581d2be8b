"""FQL: Flow Q-Learning (Park, Li & Levine, 2025).

Two policies share nothing but the data:

- a *behaviour flow* v(s, x, t), trained by flow matching to carry Gaussian noise to the data's
  actions (x_t = (1 − t)·z + t·a, target velocity a − z); integrating it with ``flow_steps`` Euler
  steps from z gives the behaviour policy's action for that noise;
- a *one-step policy* μ(s, z), which acts: trained to maximise Q(s, μ(s, z)) while staying close
  (``alpha``·‖μ(s, z) − flow(s, z)‖²) to what the behaviour flow does with the same noise.

The critic is an ensemble of two LayerNorm MLPs; its target uses the one-step policy at s' and
aggregates the two target critics by their mean (``q_agg``).  One update trains all three.

Metrics: ``critic/loss``, ``critic/q``, ``critic/target_q``, ``actor/loss``, ``actor/bc_flow_loss``,
``actor/distill_loss``, ``actor/q_loss``, ``actor/q``, ``actor/mse``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import flax.linen as nn
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
from d5rl.agents.config import Config
from d5rl.agents.encoders import make_encoder
from d5rl.agents.networks import MLP, Critic, default_init, soft_update


class FlowField(nn.Module):
    """An MLP on ``concat(encode(obs), x[, t])`` with an ``action_dim`` output: the behaviour flow's
    velocity v(s, x, t), or (without ``t``) the one-step policy's action μ(s, z)."""

    encoder: nn.Module
    hidden_dims: Sequence[int]
    action_dim: int
    layer_norm: bool = False

    @nn.compact
    def __call__(self, obs, x, t=None):
        parts = [self.encoder(obs), x] + ([t] if t is not None else [])
        h = MLP(self.hidden_dims, activate_final=True, layer_norm=self.layer_norm)(jnp.concatenate(parts, -1))
        return nn.Dense(self.action_dim, kernel_init=default_init)(h)


class FQLAgent(Agent):
    rng: Any
    critic: Any
    target_critic_params: Any
    bc_flow: Any  # v(s, x, t)
    actor: Any  # μ(s, z): the one-step policy that acts
    config: Config = nonpytree_field()
    obs_ndim: tuple = nonpytree_field()

    # --- policies ---------------------------------------------------------------------------------
    def flow_actions(self, obs, noise):
        """The behaviour flow's actions: ``flow_steps`` Euler steps from ``noise`` (no gradient)."""
        steps = self.config.flow_steps
        x = noise
        for i in range(steps):
            t = jnp.full(noise.shape[:-1] + (1,), i / steps, noise.dtype)
            x = x + self.bc_flow.apply_fn({"params": self.bc_flow.params}, obs, x, t) / steps
        return jnp.clip(x, -1.0, 1.0)

    def _act(self, params, obs, key):
        """μ(s, z) with z ~ N(0, I), clipped to the action box."""
        noise = jax.random.normal(key, _batch_shape(obs) + (self.config.action_dim,))
        return jnp.clip(self.actor.apply_fn({"params": params}, obs, noise), -1.0, 1.0)

    # --- losses -------------------------------------------------------------------------------------
    def critic_loss(self, critic_params, batch, key):
        cfg = self.config
        next_a = self._act(self.actor.params, batch["next_observations"], key)
        next_qs = self.critic.apply_fn({"params": self.target_critic_params}, batch["next_observations"], next_a)
        next_q = next_qs.mean(0) if cfg.q_agg == "mean" else next_qs.min(0)
        target = jax.lax.stop_gradient(batch["rewards"] + cfg.discount * batch["masks"] * next_q)
        qs = self.critic.apply_fn({"params": critic_params}, batch["observations"], batch["actions"])
        loss = ((qs - target[None]) ** 2).mean()
        return loss, {"critic/loss": loss, "critic/q": qs.mean(), "critic/target_q": target.mean()}

    def bc_flow_loss(self, flow_params, batch, key):
        """Flow matching on the data: predict a − z at x_t = (1 − t)·z + t·a, t ~ U[0, 1]."""
        k_z, k_t = jax.random.split(key)
        a = batch["actions"]
        z = jax.random.normal(k_z, a.shape)
        t = jax.random.uniform(k_t, a.shape[:-1] + (1,))
        pred = self.bc_flow.apply_fn({"params": flow_params}, batch["observations"], (1 - t) * z + t * a, t)
        return ((pred - (a - z)) ** 2).mean()

    def actor_loss(self, actor_params, batch, key):
        """Distil the behaviour flow into the one-step policy while maximising Q."""
        cfg = self.config
        k_z, k_eval = jax.random.split(key)
        obs = batch["observations"]
        z = jax.random.normal(k_z, batch["actions"].shape)
        target = jax.lax.stop_gradient(self.flow_actions(obs, z))
        mu = self.actor.apply_fn({"params": actor_params}, obs, z)
        distill = ((mu - target) ** 2).mean()
        q = self.critic.apply_fn({"params": self.critic.params}, obs, jnp.clip(mu, -1.0, 1.0)).mean(0)
        q_loss = -q.mean()
        if cfg.normalize_q_loss:
            q_loss = q_loss / jax.lax.stop_gradient(jnp.abs(q).mean() + 1e-8)
        loss = cfg.alpha * distill + q_loss
        mse = ((self._act(actor_params, obs, k_eval) - batch["actions"]) ** 2).mean()
        return loss, {
            "actor/loss": loss,
            "actor/distill_loss": distill,
            "actor/q_loss": q_loss,
            "actor/q": q.mean(),
            "actor/mse": mse,
        }

    def _update(self, batch):
        rng, aug_key, k_critic, k_flow, k_actor = jax.random.split(self.rng, 5)
        batch = augment_batch(aug_key, batch, self.config)
        g, critic_info = jax.grad(self.critic_loss, has_aux=True)(self.critic.params, batch, k_critic)
        critic = self.critic.apply_gradients(grads=g)
        flow_loss, g = jax.value_and_grad(self.bc_flow_loss)(self.bc_flow.params, batch, k_flow)
        bc_flow = self.bc_flow.apply_gradients(grads=g)
        # the actor is trained against the critic and the behaviour flow as they were before this update
        g, actor_info = jax.grad(self.actor_loss, has_aux=True)(self.actor.params, batch, k_actor)
        actor = self.actor.apply_gradients(grads=g)
        target = soft_update(self.target_critic_params, critic.params, self.config.tau)
        agent = self.replace(rng=rng, critic=critic, target_critic_params=target, bc_flow=bc_flow, actor=actor)
        return agent, {**critic_info, **actor_info, "actor/bc_flow_loss": flow_loss}

    # --- acting -------------------------------------------------------------------------------------
    @jax.jit
    def _sample(self, obs, seed, temperature=1.0):
        return self._act(self.actor.params, obs, seed)

    @jax.jit
    def _eval(self, obs, seed):
        return self._act(self.actor.params, obs, seed)

    @classmethod
    def create(cls, seed: int, example_observations, example_actions, config: Config | None = None):
        config = get_config() if config is None else config
        ex_obs, ex_act = prepare_example(example_observations, example_actions)
        action_dim = int(ex_act.shape[-1])
        config = config.replace(action_dim=action_dim)
        rng, k_c, k_f, k_a = jax.random.split(jax.random.PRNGKey(seed), 4)
        critic_def = Critic(make_encoder(config), config.critic_hidden_dims, 2, config.critic_layer_norm)
        flow_def = FlowField(make_encoder(config), config.actor_hidden_dims, action_dim, config.actor_layer_norm)
        actor_def = FlowField(make_encoder(config), config.actor_hidden_dims, action_dim, config.actor_layer_norm)
        t = jax.numpy.zeros(ex_act.shape[:-1] + (1,))
        critic = make_train_state(critic_def, k_c, (ex_obs, ex_act), config.lr)
        bc_flow = make_train_state(flow_def, k_f, (ex_obs, ex_act, t), config.lr)
        actor = make_train_state(actor_def, k_a, (ex_obs, ex_act), config.lr)
        return cls(
            rng=rng,
            critic=critic,
            target_critic_params=copy_tree(critic.params),
            bc_flow=bc_flow,
            actor=actor,
            config=config,
            obs_ndim=obs_ndims(ex_obs),
        )


def _batch_shape(obs) -> tuple:
    leaf = jax.tree_util.tree_leaves(obs)[0]
    return tuple(leaf.shape[:1])


def get_config() -> Config:
    return Config(
        agent_name="fql",  # name in d5rl.agents.AGENTS
        lr=3e-4,  # Adam lr of all three networks (FQL release)
        actor_hidden_dims=(512, 512, 512, 512),  # MLP widths of the behaviour flow and the one-step policy (FQL)
        critic_hidden_dims=(512, 512, 512, 512),  # MLP widths of the critics (FQL)
        critic_layer_norm=True,  # LayerNorm in the critics (FQL)
        actor_layer_norm=False,  # LayerNorm in the flow and policy networks (FQL: off)
        discount=0.99,  # γ
        tau=0.005,  # Polyak rate of the target critics (FQL)
        q_agg="mean",  # aggregation of the two target critics: "mean" (FQL default) or "min"
        alpha=10.0,  # weight of the distillation term (FQL: tuned per task, 3-10000; release default 10)
        flow_steps=10,  # Euler steps of the behaviour flow (FQL)
        normalize_q_loss=False,  # divide the Q loss by mean|Q| (FQL option; off by default)
        action_dim=None,  # set by create() from the example actions
        batch_size=256,  # minibatch size (FQL; 64 for pixels in D5RL's settings)
        **ENCODER_DEFAULTS,
    )
