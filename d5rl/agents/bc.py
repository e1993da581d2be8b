"""Behaviour cloning, as the D5RL release ran it: a Gaussian policy with a tanh-bounded mean and a fixed
unit std, so maximising the likelihood of the dataset's actions is least squares on the mean
(``-log N(a; μ, I) = ½‖a − μ‖² + const``).  The learning rate decays along a cosine (the release's kitchen and
A1 configs; its WidowX script keeps it constant: ``actor_decay_steps=0`` in the settings file), and the policy
MLP may use dropout (the release's A1 config: 0.1).

``learned_std=True`` keeps the variant that also learns the std by likelihood (a state-dependent one, or one
vector with ``state_dependent_std=False``).  Evaluation takes the mean.

Metrics: ``actor/loss`` (negative log-likelihood), ``actor/mse`` (mean vs. data action), ``actor/log_std``.
"""

from __future__ import annotations

from typing import Any

import jax
import optax

from d5rl.agents.augment import augment_batch
from d5rl.agents.common import (
    ENCODER_DEFAULTS,
    Agent,
    make_train_state,
    nonpytree_field,
    obs_ndims,
    prepare_example,
    release_actor_decay,
)
from d5rl.agents.config import Config
from d5rl.agents.encoders import make_encoder
from d5rl.agents.networks import GaussianPolicy


class BCAgent(Agent):
    rng: Any
    actor: Any
    config: Config = nonpytree_field()
    obs_ndim: tuple = nonpytree_field()

    version = 2  # 2: the release's fixed unit-std policy, cosine lr decay and dropout (1: learned std, constant lr)
    resolve_config = classmethod(release_actor_decay)  # actor_decay_steps=None: the release's decay horizon

    def actor_loss(self, actor_params, batch, key):
        dist = self.actor.apply_fn(
            {"params": actor_params}, self.normalize(batch["observations"]), train=True, rngs={"dropout": key}
        )
        loss = -dist.log_prob(batch["actions"]).mean()
        mse = ((dist.mode() - batch["actions"]) ** 2).sum(-1).mean()
        return loss, {"actor/loss": loss, "actor/mse": mse, "actor/log_std": dist.log_std.mean()}

    def _update(self, batch):
        rng, aug_key, key = jax.random.split(self.rng, 3)
        batch = augment_batch(aug_key, batch, self.config)
        grads, info = jax.grad(self.actor_loss, has_aux=True)(self.actor.params, batch, key)
        return self.replace(rng=rng, actor=self.actor.apply_gradients(grads=grads)), info

    @classmethod
    def create(cls, seed: int, example_observations, example_actions, config: Config | None = None):
        config = get_config() if config is None else config
        ex_obs, ex_act = prepare_example(example_observations, example_actions)
        rng, k_actor = jax.random.split(jax.random.PRNGKey(seed))
        actor_def = GaussianPolicy(
            make_encoder(config),
            config.hidden_dims,
            ex_act.shape[-1],
            tanh_squash=False,
            log_std_min=config.log_std_min,
            log_std_max=config.log_std_max,
            state_dependent_std=config.state_dependent_std,
            fixed_std=not config.learned_std,
            dropout_rate=config.dropout_rate or None,
        )
        lr = config.actor_lr
        if config.actor_decay_steps:
            lr = optax.cosine_decay_schedule(config.actor_lr, config.actor_decay_steps)
        actor = make_train_state(actor_def, k_actor, (ex_obs,), lr)
        return cls(rng=rng, actor=actor, config=config, obs_ndim=obs_ndims(ex_obs))


def get_config() -> Config:
    return Config(
        agent_name="bc",  # name in d5rl.agents.AGENTS
        actor_lr=3e-4,  # Adam learning rate (release kitchen BC; A1 1e-3 and WidowX 1e-4 in the settings file)
        actor_decay_steps=None,  # cosine decay of the lr to 0 over this many updates; None = the release's
        # horizon (release_actor_decay); 0 = constant (the release's WidowX BC)
        hidden_dims=(256, 256),  # MLP widths of the policy
        dropout_rate=0.0,  # dropout in the policy MLP while training (release A1 config: 0.1)
        learned_std=False,  # False: the release's fixed unit std (least squares); True: learn the std by likelihood
        log_std_min=-5.0,  # with learned_std: clip of the policy's log-std
        log_std_max=2.0,  # with learned_std: upper clip of the policy's log-std
        state_dependent_std=True,  # with learned_std: log-std from the network (False = one learned vector)
        normalize_observations=False,  # standardise state observations with the dataset's mean and std
        obs_mean=None,  # per-dimension mean, filled by `d5rl train` when normalizing (None: identity)
        obs_std=None,  # per-dimension std + 1e-3, filled with obs_mean
        batch_size=256,  # minibatch size (256 state, 64 pixels in D5RL)
        **ENCODER_DEFAULTS,
    )
