"""CQL: Conservative Q-Learning (Kumar et al., 2020), the CQL(H) variant on SAC.

The critic's TD loss gets a regulariser α · (logsumexp_a Q(s, a) − Q(s, a_data)),
the log-sum-exp estimated by importance sampling over uniform random actions
and policy actions at s (``cql_n_actions`` of each; the D5RL release's ``critic_updater.py``: 4, its
``max_q_backup`` TD target takes the best of as many actions of π(s')).  ``cql_next_actions`` adds the
CQL paper's actions of π(s').  Actor and
temperature are SAC's.  Cal-QL (:mod:`d5rl.agents.calql`) overrides
:meth:`CQLAgent.bound_policy_q`.

Metrics: ``critic/loss``, ``critic/td_loss``, ``critic/cql_loss``, ``critic/q``,
``critic/target_q``, ``critic/ood_q``, ``actor/loss``, ``actor/entropy``,
``actor/temperature``, ``actor/temperature_loss``.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp

from d5rl.agents.augment import augment_batch
from d5rl.agents.common import (
    ENCODER_DEFAULTS,
    Agent,
    copy_tree,
    nonpytree_field,
    obs_ndims,
    prepare_example,
    sac_train_states,
)
from d5rl.agents.config import Config
from d5rl.agents.networks import soft_update


class CQLAgent(Agent):
    rng: Any
    actor: Any
    critic: Any
    target_critic_params: Any
    temp: Any
    config: Config = nonpytree_field()
    obs_ndim: tuple = nonpytree_field()

    version = 2  # 2: the release's form, 4 actions of π(s) and uniform, max-Q backup (1: 10 of π(s), π(s'), uniform)

    def bound_policy_q(self, q, batch):
        """Hook on Q of policy actions inside the CQL term, ``(num_qs, n, B)``; CQL leaves it alone."""
        return q, {}

    def _policy_q(self, critic_params, features, actions):
        """Q of ``actions`` (n, B, A) at encoded observations (B, F) → (num_qs, n, B)."""
        n, b, _ = actions.shape
        feats = jnp.broadcast_to(features, (n,) + features.shape).reshape(n * b, -1)
        q = self.critic.apply_fn({"params": critic_params}, feats, actions.reshape(n * b, -1), method="head")
        return q.reshape(q.shape[0], n, b)

    def critic_loss(self, critic_params, batch, key):
        cfg = self.config
        k_next, k_rand, k_cur, k_nxt = jax.random.split(key, 4)
        apply_actor = lambda obs: self.actor.apply_fn({"params": self.actor.params}, obs)  # noqa: E731
        dist_next = apply_actor(batch["next_observations"])
        n, (b, a_dim) = cfg.cql_n_actions, batch["actions"].shape
        # --- TD target ---
        temperature = self.temp.apply_fn({"params": self.temp.params})
        if cfg.cql_max_target_backup:  # n actions from π(s'), the best one's value (release: max_q_backup)
            next_a, next_logp = dist_next.sample_n_and_log_prob(k_next, n)
            next_q = self._policy_q(
                self.target_critic_params,
                self.critic.apply_fn(
                    {"params": self.target_critic_params}, batch["next_observations"], method="encode"
                ),
                next_a,
            ).min(0)
            best = jnp.argmax(next_q, axis=0)
            target_q = jnp.take_along_axis(next_q, best[None], 0)[0]
            next_logp = jnp.take_along_axis(next_logp, best[None], 0)[0]
        else:
            next_a, next_logp = dist_next.sample_and_log_prob(k_next)
            target_q = self.critic.apply_fn(
                {"params": self.target_critic_params}, batch["next_observations"], next_a
            ).min(0)
        if cfg.backup_entropy:
            target_q = target_q - temperature * next_logp
        target = jax.lax.stop_gradient(batch["rewards"] + cfg.discount * batch["masks"] * target_q)
        features = self.critic.apply_fn({"params": critic_params}, batch["observations"], method="encode")
        qs = self.critic.apply_fn({"params": critic_params}, features, batch["actions"], method="head")
        td_loss = ((qs - target[None]) ** 2).mean(axis=1).sum()
        # --- conservative term ---
        rand_a = jax.random.uniform(k_rand, (n, b, a_dim), minval=-1.0, maxval=1.0)
        cur_a, cur_logp = jax.lax.stop_gradient(apply_actor(batch["observations"]).sample_n_and_log_prob(k_cur, n))
        q_rand = self._policy_q(critic_params, features, rand_a)
        q_cur, bound_info = self.bound_policy_q(self._policy_q(critic_params, features, cur_a), batch)
        if cfg.cql_next_actions:  # the CQL paper's third set: actions of π(s') valued at s
            nxt_a, nxt_logp = jax.lax.stop_gradient(dist_next.sample_n_and_log_prob(k_nxt, n))
            q_nxt, _ = self.bound_policy_q(self._policy_q(critic_params, features, nxt_a), batch)
            policy_parts = (
                [q_nxt - nxt_logp[None], q_cur - cur_logp[None]] if cfg.cql_importance_sample else [q_nxt, q_cur]
            )
        else:
            policy_parts = [q_cur - cur_logp[None]] if cfg.cql_importance_sample else [q_cur]
        if cfg.cql_importance_sample:
            cat = jnp.concatenate([q_rand - a_dim * math.log(0.5), *policy_parts], 1)
        else:
            cat = jnp.concatenate([q_rand, *policy_parts, qs[:, None]], axis=1)
        ood = jax.nn.logsumexp(cat / cfg.cql_temp, axis=1) * cfg.cql_temp  # (num_qs, B)
        cql_diff = jnp.clip(ood - qs, cfg.cql_clip_diff_min, cfg.cql_clip_diff_max).mean(axis=1)
        cql_loss = cfg.cql_alpha * cql_diff.sum()
        loss = td_loss + cql_loss
        return loss, {
            "critic/loss": loss,
            "critic/td_loss": td_loss,
            "critic/cql_loss": cql_loss,
            "critic/q": qs.mean(),
            "critic/target_q": target.mean(),
            "critic/ood_q": ood.mean(),
            **bound_info,
        }

    def actor_loss(self, actor_params, batch, key):
        dist = self.actor.apply_fn({"params": actor_params}, batch["observations"])
        actions, logp = dist.sample_and_log_prob(key)
        q = self.critic.apply_fn({"params": self.critic.params}, batch["observations"], actions).min(0)
        temperature = self.temp.apply_fn({"params": self.temp.params})
        loss = (temperature * logp - q).mean()
        return loss, {"actor/loss": loss, "actor/entropy": -logp.mean()}

    def temperature_loss(self, temp_params, entropy):
        temperature = self.temp.apply_fn({"params": temp_params})
        loss = temperature * (entropy - self.config.target_entropy)
        return loss, {"actor/temperature": temperature, "actor/temperature_loss": loss}

    def _update(self, batch):
        rng, aug_key, k_critic, k_actor = jax.random.split(self.rng, 4)
        batch = augment_batch(aug_key, batch, self.config)
        g, actor_info = jax.grad(self.actor_loss, has_aux=True)(self.actor.params, batch, k_actor)
        actor = self.actor.apply_gradients(grads=g)
        temp = self.temp
        if self.config.autotune_temperature:
            g, temp_info = jax.grad(self.temperature_loss, has_aux=True)(temp.params, actor_info["actor/entropy"])
            temp = temp.apply_gradients(grads=g)
        else:
            temp_info = {"actor/temperature": temp.apply_fn({"params": temp.params})}
        g, critic_info = jax.grad(self.critic_loss, has_aux=True)(self.critic.params, batch, k_critic)
        critic = self.critic.apply_gradients(grads=g)
        target = soft_update(self.target_critic_params, critic.params, self.config.tau)
        agent = self.replace(rng=rng, actor=actor, temp=temp, critic=critic, target_critic_params=target)
        return agent, {**critic_info, **actor_info, **temp_info}

    @classmethod
    def create(cls, seed: int, example_observations, example_actions, config: Config | None = None):
        config = get_config() if config is None else config
        ex_obs, ex_act = prepare_example(example_observations, example_actions)
        if config.target_entropy is None:
            config = config.replace(target_entropy=-float(ex_act.shape[-1]))
        rng, *keys = jax.random.split(jax.random.PRNGKey(seed), 4)
        actor, critic, temp = sac_train_states(config, keys, ex_obs, ex_act)
        return cls(
            rng=rng,
            actor=actor,
            critic=critic,
            target_critic_params=copy_tree(critic.params),
            temp=temp,
            config=config,
            obs_ndim=obs_ndims(ex_obs),
        )


def get_config() -> Config:
    return Config(
        agent_name="cql",  # name in d5rl.agents.AGENTS
        actor_lr=1e-4,  # policy Adam lr (CQL paper and D5RL)
        critic_lr=3e-4,  # Q Adam lr (CQL paper and D5RL)
        temp_lr=3e-4,  # SAC temperature Adam lr
        hidden_dims=(256, 256),  # MLP widths
        discount=0.99,  # γ
        tau=0.005,  # Polyak rate of the target Q
        num_qs=2,  # clipped double Q
        critic_layer_norm=False,  # LayerNorm in the critics
        cql_alpha=5.0,  # weight α of the conservative term (D5RL sweeps 0.1, 1, 5, 10)
        cql_n_actions=4,  # sampled actions per kind for the log-sum-exp (release critic_updater: NUM_CQL_REPEAT 4)
        cql_next_actions=False,  # also π(s') actions in the log-sum-exp (CQL paper); the release: π(s) and uniform
        cql_max_target_backup=True,  # TD target: max over cql_n_actions actions of π(s') (release max_q_backup)
        cql_temp=1.0,  # temperature of the log-sum-exp
        cql_importance_sample=True,  # CQL(H) with importance weights (CQL paper, App. F)
        cql_clip_diff_min=-1e9,  # clip of logsumexp − Q_data (JaxCQL; ±inf = no clip)
        cql_clip_diff_max=1e9,  # upper clip of that difference
        backup_entropy=False,  # no entropy term in the TD target (CQL)
        autotune_temperature=True,  # learn SAC's α towards target_entropy
        init_temperature=1.0,  # initial SAC α
        target_entropy=None,  # None = −|A| (SAC)
        log_std_min=-20.0,  # clip of the policy's log-std (JaxCQL)
        log_std_max=2.0,  # upper clip of the policy's log-std
        batch_size=256,  # minibatch size (256 state, 64 pixels in D5RL)
        **ENCODER_DEFAULTS,
    )
