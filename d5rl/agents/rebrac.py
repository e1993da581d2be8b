"""ReBRAC (Tarasov et al., 2023, "Revisiting the Minimalist Approach to Offline Reinforcement
Learning"): TD3+BC with LayerNorm critics, a deeper network, and behaviour penalties on both sides.

Actor: maximise λ·Q(s, π(s)) − β_actor·‖π(s) − a‖², with λ = 1 / mean|Q| (stop-gradient).
Critic: clipped double Q with target-policy smoothing noise, whose target subtracts
β_critic·‖a' − a'_data‖², the distance of the smoothed target action from the action the data
took next (``next_actions`` in the batch).  The actor and the targets update every
``policy_freq`` critic updates, as in TD3 (the update schedule is :class:`TD3BCAgent`'s).

Metrics: ``critic/loss``, ``critic/q``, ``critic/target_q``, ``critic/bc_penalty``,
``actor/loss``, ``actor/bc_mse``, ``actor/q``, ``actor/lambda``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from d5rl.agents.common import ENCODER_DEFAULTS
from d5rl.agents.config import Config
from d5rl.agents.td3bc import TD3BCAgent


class ReBRACAgent(TD3BCAgent):
    extra_batch_keys = ("next_actions",)  # the critic's penalty compares with the data's next action

    def critic_loss(self, critic_params, batch, key):
        cfg = self.config
        next_a = self.actor.apply_fn({"params": self.target_actor_params}, batch["next_observations"])
        noise = jnp.clip(cfg.policy_noise * jax.random.normal(key, next_a.shape), -cfg.noise_clip, cfg.noise_clip)
        next_a = jnp.clip(next_a + noise, -1.0, 1.0)
        penalty = ((next_a - batch["next_actions"]) ** 2).sum(-1)
        next_q = self.critic.apply_fn({"params": self.target_critic_params}, batch["next_observations"], next_a).min(0)
        target = batch["rewards"] + cfg.discount * batch["masks"] * (next_q - cfg.critic_bc_coef * penalty)
        target = jax.lax.stop_gradient(target)
        qs = self.critic.apply_fn({"params": critic_params}, batch["observations"], batch["actions"])
        loss = ((qs - target[None]) ** 2).mean(axis=1).sum()
        return loss, {
            "critic/loss": loss,
            "critic/q": qs.mean(),
            "critic/target_q": target.mean(),
            "critic/bc_penalty": penalty.mean(),
        }

    def actor_loss(self, actor_params, batch):
        pi = self.actor.apply_fn({"params": actor_params}, batch["observations"])
        q = self.critic.apply_fn({"params": self.critic.params}, batch["observations"], pi).min(0)
        lam = jax.lax.stop_gradient(1.0 / (jnp.abs(q).mean() + 1e-8))
        bc = ((pi - batch["actions"]) ** 2).sum(-1)
        loss = (self.config.actor_bc_coef * bc - lam * q).mean()
        return loss, {"actor/loss": loss, "actor/bc_mse": bc.mean(), "actor/q": q.mean(), "actor/lambda": lam}

    @classmethod
    def create(cls, seed: int, example_observations, example_actions, config: Config | None = None):
        return super().create(seed, example_observations, example_actions, get_config() if config is None else config)


def get_config() -> Config:
    return Config(
        agent_name="rebrac",  # name in d5rl.agents.AGENTS
        actor_lr=1e-3,  # policy Adam lr (ReBRAC paper, D4RL)
        critic_lr=1e-3,  # Q Adam lr (ReBRAC paper, D4RL)
        hidden_dims=(256, 256, 256),  # MLP widths of actor and critics: three layers (ReBRAC paper)
        discount=0.99,  # γ
        tau=0.005,  # Polyak rate of the targets (ReBRAC paper)
        actor_bc_coef=0.01,  # β_actor (ReBRAC tunes per dataset in {5e-4 .. 1}; OGBench/FQL release examples 0.01)
        critic_bc_coef=0.01,  # β_critic (ReBRAC tunes per dataset in {0, 1e-3, 1e-2, 0.1, 0.5}; release examples 0.01)
        policy_noise=0.2,  # std of target-policy smoothing noise (TD3, ReBRAC)
        noise_clip=0.5,  # clip of that noise (TD3, ReBRAC)
        policy_freq=2,  # actor/target update every this many critic updates (TD3, ReBRAC)
        exploration_noise=0.1,  # Gaussian action noise when collecting online data (TD3)
        critic_layer_norm=True,  # LayerNorm in the critics: ReBRAC's main ingredient
        actor_layer_norm=False,  # LayerNorm in the actor (ReBRAC: off for most datasets)
        normalize_observations=False,  # ReBRAC does not standardise states (TD3+BC does)
        obs_mean=None,  # per-dimension mean when normalize_observations (None: identity)
        obs_std=None,  # per-dimension std when normalize_observations
        batch_size=256,  # minibatch size (ReBRAC: 1024 on D4RL; 256 as in the OGBench/FQL release, CPU-friendly)
        **ENCODER_DEFAULTS,
    )
