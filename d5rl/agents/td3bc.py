"""TD3+BC (Fujimoto & Gu, 2021): TD3 whose actor loss adds a behaviour-cloning term.

Actor: maximise λ·Q(s, π(s)) − (π(s) − a)², with λ = α / mean|Q| (stop-gradient).
Critic: clipped double Q with target-policy smoothing noise.  The actor and the
targets update every ``policy_freq`` critic updates.

The defaults are the TD3+BC authors' (the paper's choice for state tasks).  For pixels the paper names
jaxrl2's TD3+BC, whose form the D5RL release runs (``pixel_td3bc/{actor,critic}_updater.py``) and the
settings file selects: the actor is the mean of a unit-std Gaussian, clipped rather than tanh-squashed
(``actor_output="clip"``); the target action is a sample of that Gaussian (``target_policy_std=1``) plus
smoothing noise of std 0.1 clipped at 0.5; the actor and the targets update at every step
(``policy_freq=1``); the actor's Q is the mean of the two critics (``actor_q="mean"``), not the first.

Metrics: ``critic/loss``, ``critic/q``, ``critic/target_q``, ``actor/loss``,
``actor/bc_mse``, ``actor/q``, ``actor/lambda``.
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
from d5rl.agents.encoders import is_pixel_obs, make_encoder
from d5rl.agents.networks import Critic, DeterministicPolicy, soft_update

ACTOR_METRICS = ("actor/loss", "actor/bc_mse", "actor/q", "actor/lambda")


def no_actor_metrics():
    """The actor metrics of an update without an actor step."""
    return {k: jnp.zeros((), jnp.float32) for k in ACTOR_METRICS}


class TD3BCAgent(Agent):
    rng: Any
    actor: Any
    target_actor_params: Any
    critic: Any
    target_critic_params: Any
    config: Config = nonpytree_field()
    obs_ndim: tuple = nonpytree_field()

    def critic_loss(self, critic_params, batch, key):
        cfg = self.config
        next_a = self.actor.apply_fn({"params": self.target_actor_params}, batch["next_observations"])
        if cfg.target_policy_std:  # a sample of the target actor's Gaussian (the release's pixel TD3+BC)
            next_a = next_a + cfg.target_policy_std * jax.random.normal(jax.random.fold_in(key, 1), next_a.shape)
        noise = jnp.clip(cfg.policy_noise * jax.random.normal(key, next_a.shape), -cfg.noise_clip, cfg.noise_clip)
        next_a = jnp.clip(next_a + noise, -1.0, 1.0)
        next_q = self.critic.apply_fn({"params": self.target_critic_params}, batch["next_observations"], next_a).min(0)
        target = jax.lax.stop_gradient(batch["rewards"] + cfg.discount * batch["masks"] * next_q)
        qs = self.critic.apply_fn({"params": critic_params}, batch["observations"], batch["actions"])
        loss = ((qs - target[None]) ** 2).mean(axis=1).sum()
        return loss, {"critic/loss": loss, "critic/q": qs.mean(), "critic/target_q": target.mean()}

    def actor_loss(self, actor_params, batch):
        pi = self.actor.apply_fn({"params": actor_params}, batch["observations"])
        qs = self.critic.apply_fn({"params": self.critic.params}, batch["observations"], pi)
        q = qs.mean(0) if self.config.actor_q == "mean" else qs[0]
        lam = jax.lax.stop_gradient(self.config.alpha / (jnp.abs(q).mean() + 1e-8))
        bc = ((pi - batch["actions"]) ** 2).mean()
        loss = -lam * q.mean() + bc
        return loss, {"actor/loss": loss, "actor/bc_mse": bc, "actor/q": q.mean(), "actor/lambda": lam}

    def _update_actor(self, batch):
        g, info = jax.grad(self.actor_loss, has_aux=True)(self.actor.params, batch)
        actor = self.actor.apply_gradients(grads=g)
        tau = self.config.tau
        return self.replace(
            actor=actor,
            target_actor_params=soft_update(self.target_actor_params, actor.params, tau),
            target_critic_params=soft_update(self.target_critic_params, self.critic.params, tau),
        ), info

    def _critic_step(self, batch):
        """Augment and normalise ``batch``, update the critic; returns ``(agent, batch, metrics)``."""
        rng, aug_key, key = jax.random.split(self.rng, 3)
        batch = augment_batch(aug_key, batch, self.config)
        batch = {
            **batch,
            "observations": self.normalize(batch["observations"]),
            "next_observations": self.normalize(batch["next_observations"]),
        }
        g, critic_info = jax.grad(self.critic_loss, has_aux=True)(self.critic.params, batch, key)
        return self.replace(rng=rng, critic=self.critic.apply_gradients(grads=g)), batch, critic_info

    def _actor_due(self):
        # critic.step counts critic updates; the first update (step 1) also trains the actor.
        return self.critic.step % self.config.policy_freq == 0  # before this update's critic step

    def _update(self, batch):
        due = self._actor_due()
        agent, batch, critic_info = self._critic_step(batch)
        if not is_pixel_obs(batch["observations"]):
            agent, actor_info = jax.lax.cond(
                due, lambda a: a._update_actor(batch), lambda a: (a, no_actor_metrics()), agent
            )
        else:
            # XLA:CPU runs convolutions inside a lax.cond branch ~10-20x slower (6.6 s vs 0.55 s per
            # pixel update), so inside one program (update_many) pixel agents compute the actor step
            # and select it; update() and update_donated() pick one of two programs instead.
            updated, actor_info = agent._update_actor(batch)
            agent = jax.tree_util.tree_map(lambda new, old: jnp.where(due, new, old), updated, agent)
            actor_info = {k: jnp.where(due, v, 0.0) for k, v in actor_info.items()}
        return agent, {**critic_info, **actor_info}

    def _update_pixels(self, batch, with_actor: bool):
        agent, batch, critic_info = self._critic_step(batch)
        if with_actor:
            agent, actor_info = agent._update_actor(batch)
        else:
            actor_info = no_actor_metrics()
        return agent, {**critic_info, **actor_info}

    _pixel_update = jax.jit(_update_pixels, static_argnames="with_actor")
    _pixel_update_donated = jax.jit(_update_pixels, static_argnames="with_actor", donate_argnums=0)

    def update(self, batch):
        """One update. For pixel observations the host reads the step count and runs a program
        with or without the actor step, so the delayed actor costs nothing on the other steps."""
        if not is_pixel_obs(batch["observations"]):
            return Agent.update(self, batch)
        return self._pixel_update(batch, with_actor=bool(self._actor_due()))

    def update_donated(self, batch):
        """:meth:`update` that donates the old agent's buffers (training loops)."""
        if not is_pixel_obs(batch["observations"]):
            return Agent.update_donated(self, batch)
        return self._pixel_update_donated(batch, with_actor=bool(self._actor_due()))

    @jax.jit
    def _sample(self, obs, seed, temperature=1.0):
        a = self.actor.apply_fn({"params": self.actor.params}, self.normalize(obs))
        noise = self.config.exploration_noise * temperature * jax.random.normal(seed, a.shape)
        return jnp.clip(a + noise, -1.0, 1.0)

    @jax.jit
    def _eval(self, obs, seed):
        return self.actor.apply_fn({"params": self.actor.params}, self.normalize(obs))

    @classmethod
    def create(cls, seed: int, example_observations, example_actions, config: Config | None = None):
        config = get_config() if config is None else config
        ex_obs, ex_act = prepare_example(example_observations, example_actions)
        rng, k_a, k_c = jax.random.split(jax.random.PRNGKey(seed), 3)
        output, actor_q = config.get("actor_output", "tanh"), config.get("actor_q", "first")  # ReBRAC: TD3's
        if output not in ("tanh", "clip") or actor_q not in ("first", "mean"):
            raise ConfigError(
                f"{config.agent_name}: actor_output={output!r}, actor_q={actor_q!r}",
                "actor_output is tanh or clip; actor_q is first or mean",
            )
        actor_def = DeterministicPolicy(
            make_encoder(config),
            config.hidden_dims,
            ex_act.shape[-1],
            layer_norm=config.actor_layer_norm,
            output=output,
        )
        critic_def = Critic(make_encoder(config), config.hidden_dims, 2, config.critic_layer_norm)
        actor = make_train_state(actor_def, k_a, (ex_obs,), config.actor_lr)
        critic = make_train_state(critic_def, k_c, (ex_obs, ex_act), config.critic_lr)
        return cls(
            rng=rng,
            actor=actor,
            target_actor_params=copy_tree(actor.params),
            critic=critic,
            target_critic_params=copy_tree(critic.params),
            config=config,
            obs_ndim=obs_ndims(ex_obs),
        )


def get_config() -> Config:
    return Config(
        agent_name="td3bc",  # name in d5rl.agents.AGENTS
        actor_lr=3e-4,  # policy Adam lr (TD3+BC paper)
        critic_lr=3e-4,  # Q Adam lr (TD3+BC paper)
        hidden_dims=(256, 256),  # MLP widths (TD3+BC paper)
        discount=0.99,  # γ
        tau=0.005,  # Polyak rate of the targets
        alpha=2.5,  # α in λ = α / mean|Q| (TD3+BC paper)
        policy_noise=0.2,  # std of target-policy smoothing noise (TD3; release pixel TD3+BC: 0.1)
        noise_clip=0.5,  # clip of that noise (TD3)
        target_policy_std=0.0,  # std of a Gaussian around the target action before the noise (release pixels: 1)
        policy_freq=2,  # actor/target update every this many critic updates (TD3; release pixels: 1)
        actor_output="tanh",  # tanh(f(s)) (TD3) or "clip": f(s) clipped to [-1, 1] (release pixels)
        actor_q="first",  # the actor maximises Q1 (TD3+BC) or "mean": the mean of both critics (release pixels)
        exploration_noise=0.1,  # Gaussian action noise when collecting online data (TD3)
        critic_layer_norm=False,  # LayerNorm in the critics
        actor_layer_norm=False,  # LayerNorm in the actor
        normalize_observations=True,  # standardise state observations with the dataset's statistics (TD3+BC)
        obs_mean=None,  # per-dimension mean, filled by `d5rl train` when normalizing (None: identity)
        obs_std=None,  # per-dimension std + 1e-3 (TD3+BC's epsilon), filled alike
        batch_size=256,  # minibatch size (256 state, 64 pixels in D5RL)
        **ENCODER_DEFAULTS,
    )
