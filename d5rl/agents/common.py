"""Pieces every agent shares: the agent base class, train states, observation batching.

An agent is an immutable Flax struct.  Subclasses implement ``_update(batch)``
(pure, returns ``(agent, metrics)``); the base class jits it as ``update`` and
offers ``update_many`` (several updates in one ``lax.scan``; worth it for MLPs
on CPU, not for CNNs) plus checkpoint (de)serialisation.
"""

from __future__ import annotations

import functools

import flax
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax.training.train_state import TrainState

from d5rl.agents.config import Config
from d5rl.agents.encoders import make_encoder
from d5rl.agents.networks import Critic, GaussianPolicy, Temperature


def nonpytree_field(**kwargs):
    return flax.struct.field(pytree_node=False, **kwargs)


# Defaults every agent carries for pixel observations (ignored for state observations).
ENCODER_DEFAULTS = dict(
    encoder_channels=(16, 32, 32),  # IMPALA stack widths (Espeholt et al. 2018; D5RL appendix B)
    encoder_latent_dim=50,  # Dense+LayerNorm+tanh projection of CNN features (DrQ); 0 = none
    augment=True,  # DrQ augmentation of pixel observations during training
    shift_pad=4,  # random-shift padding in pixels (DrQ)
    color_jitter=True,  # colour jitter on top of the random shift (D5RL appendix B)
)


def obs_ndims(example_observations) -> tuple:
    """ndim of each observation leaf *without* a batch axis (example obs carry one)."""
    return tuple(np.ndim(x) - 1 for x in jax.tree_util.tree_leaves(example_observations))


def to_batched(observations, ndims: tuple):
    """Add a batch axis to a single observation; returns (obs, was_single)."""
    leaves = jax.tree_util.tree_leaves(observations)
    single = np.ndim(leaves[0]) == ndims[0]
    if single:
        observations = jax.tree_util.tree_map(lambda x: np.asarray(x)[None], observations)
    return observations, single


def make_train_state(module: nn.Module, key, inputs: tuple, lr: float | optax.Schedule, **init_kwargs) -> TrainState:
    params = module.init(key, *inputs, **init_kwargs)["params"]
    state = TrainState.create(apply_fn=module.apply, params=params, tx=optax.adam(lr))
    # Strongly typed leaves everywhere: an agent must have the same avals before and after
    # an update, or every jitted function compiles twice.
    return state.replace(step=jnp.zeros((), jnp.int32))


def observation_stats(observations, eps: float = 1e-3) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Per-dimension mean and std + ``eps`` of state observations (TD3+BC's normalization)."""
    obs = np.asarray(observations, dtype=np.float64)
    return tuple(float(x) for x in obs.mean(0)), tuple(float(x) for x in obs.std(0) + eps)


class Agent(flax.struct.PyTreeNode):
    """Base class.  Subclasses declare ``rng``, their train states, ``config`` and ``obs_ndim``.

    What differs between algorithms in how they are trained lives here, as class attributes and
    hooks the training loop calls, never as name checks in the loop.
    """

    # Version of the agent's algorithm: bumped whenever a change to its code changes what a run computes, so
    # results trained with the older code are listed as stale (d5rl.runner.grid.stale_reason) and rerun.
    version = 1
    # Whether an offline-to-online run first trains this agent offline (False: RLPD, whose online
    # batches are half offline data, starts its online phase from scratch and takes no offline steps).
    offline_pretraining = True
    # Batch keys beyond observations/actions/rewards/masks/next_observations ("mc_returns": CalQL).
    extra_batch_keys = ()  # (a class attribute, not a field)

    # --- configuration hooks --------------------------------------------------------------------
    @classmethod
    def resolve_config(cls, config: Config, *, offline_steps: int, online_steps: int) -> Config:
        """The config of a run of this length (e.g. "auto" learning-rate schedules); identity here."""
        return config

    @classmethod
    def fit_config(cls, config: Config, dataset) -> Config:
        """The config completed from the training data: the per-dimension mean and std of state
        observations when the agent's config has ``normalize_observations`` on (TD3+BC's standardisation;
        pixel observations are left alone)."""
        if not config.get("normalize_observations") or config.get("obs_mean") is not None:
            return config
        obs = dataset.observations
        if isinstance(obs, dict):
            return config
        mean, std = observation_stats(obs)
        return config.replace(obs_mean=mean, obs_std=std)

    def normalize(self, obs):
        """State observations standardised with the statistics :meth:`fit_config` put in the config;
        identity for pixel observations and for agents or runs without statistics."""
        if isinstance(obs, dict) or self.config.get("obs_mean") is None:
            return obs
        return (obs - jnp.asarray(self.config.obs_mean, jnp.float32)) / jnp.asarray(self.config.obs_std, jnp.float32)

    # --- how the loop feeds the agent ---------------------------------------------------------------
    def samples_per_update(self) -> int:
        """Transitions one :meth:`update` consumes."""
        return int(self.config.batch_size)

    def online_split(self, offline_ratio: float) -> tuple[int, int]:
        """``(offline, online)`` transitions of one online-phase update."""
        n = self.samples_per_update()
        n_off = int(round(n * offline_ratio))
        return n_off, n - n_off

    def mix_online(self, offline: dict, online: dict) -> dict:
        """One online-phase batch from its offline and online parts (concatenated)."""
        return jax.tree_util.tree_map(lambda x, y: np.concatenate([x, y]), offline, online)

    @property
    def default_offline_ratio(self) -> float:
        """Share of every online-phase batch drawn from the offline data (loop setting ``offline_ratio``)."""
        return 0.5

    @property
    def default_start_steps(self) -> int:
        """Random-action environment steps before online updates (loop setting ``start_steps``)."""
        return 0

    def _update(self, batch):  # pragma: no cover - abstract
        raise NotImplementedError

    @jax.jit
    def update(self, batch):
        """One gradient update (for RLPD: one UTD round); returns ``(new_agent, metrics)``."""
        return self._update(batch)

    @functools.partial(jax.jit, donate_argnums=0)
    def update_many(self, batches):
        """``len(batches)`` updates in one ``lax.scan`` (batches stacked on a leading axis).

        Donates the agent's buffers: use only the returned agent afterwards.
        Returns metrics averaged over the updates.
        """
        agent, metrics = jax.lax.scan(lambda a, b: a._update(b), self, batches)
        return agent, jax.tree_util.tree_map(jnp.mean, metrics)

    @functools.partial(jax.jit, donate_argnums=0)
    def update_donated(self, batch):
        """:meth:`update` that donates the old agent's buffers (training loops)."""
        return self._update(batch)

    # --- acting -----------------------------------------------------------------------------
    def sample_actions(self, observations, seed=None, temperature: float = 1.0):
        """Stochastic actions for exploration; a single observation gives a single action."""
        obs, single = to_batched(observations, self.obs_ndim)
        if seed is None:
            seed = self.rng
        a = self._sample(obs, seed, temperature)
        return a[0] if single else a

    def eval_actions(self, observations, seed=None):
        """Deterministic (or, for diffusion and flow policies, seeded) actions for evaluation.

        ``seed``: one key for the whole batch, or a stack of keys, one per row (shape ``(batch, 2)``):
        then each row's action depends only on its observation and its key, not on the rows beside it,
        which is what lets evaluation step any number of episodes together.
        """
        obs, single = to_batched(observations, self.obs_ndim)
        if seed is not None and np.ndim(seed) == 2:
            a = self._eval_rows(obs, jnp.asarray(seed))
        else:
            a = self._eval(obs, self.rng if seed is None else seed)
        return a[0] if single else a

    @jax.jit
    def _eval_rows(self, obs, keys):
        def one(o, k):
            return self._eval(jax.tree_util.tree_map(lambda x: x[None], o), k)[0]

        return jax.vmap(one)(obs, keys)

    @functools.partial(jax.jit, static_argnames=("temperature",))
    def _sample(self, obs, seed, temperature=1.0):
        dist = self.actor.apply_fn({"params": self.actor.params}, self.normalize(obs), temperature)
        return jnp.clip(dist.sample(seed), -1, 1)

    @jax.jit
    def _eval(self, obs, seed):
        dist = self.actor.apply_fn({"params": self.actor.params}, self.normalize(obs))
        return jnp.clip(dist.mode(), -1, 1)

    # --- config / checkpoints -------------------------------------------------------------------
    def get_config(self) -> Config:
        return self.config

    def to_bytes(self) -> bytes:
        return flax.serialization.to_bytes(self)

    def from_bytes(self, data: bytes):
        """Restore state saved by :meth:`to_bytes` into an agent created with the same config."""
        return flax.serialization.from_bytes(self, data)


def auto_actor_decay(cls, config: Config, *, offline_steps: int, online_steps: int) -> Config:
    """A :meth:`Agent.resolve_config` (``resolve_config = classmethod(auto_actor_decay)``):
    ``actor_decay_steps=None`` ("auto") makes the policy lr decay to 0 over an offline-only run (IQL's and
    IDQL's reference implementations) and stay constant when the run fine-tunes online."""
    if config.actor_decay_steps is None:
        return config.replace(actor_decay_steps=int(offline_steps) if online_steps == 0 else 0)
    return config


def release_actor_decay(cls, config: Config, *, offline_steps: int, online_steps: int) -> Config:
    """A :meth:`Agent.resolve_config`: ``actor_decay_steps=None`` ("auto") makes the policy lr decay along a
    cosine over the release's horizon, its offline plus online updates.  The release's kitchen and A1 scripts
    set ``decay_steps = max_gradient_steps + max_online_gradient_steps`` (500k + 500k) also when they train
    offline only, so an offline-only run of N updates decays over 2N and ends at half its initial lr."""
    if config.actor_decay_steps is None:
        return config.replace(actor_decay_steps=int(offline_steps) + int(online_steps or offline_steps))
    return config


def sac_train_states(config: Config, keys, ex_obs, ex_act, critic_dropout: float | None = None):
    """``(actor, critic, temperature)`` train states of a SAC-style agent (CQL, CalQL, RLPD): a tanh-squashed
    Gaussian policy, a critic ensemble and the entropy temperature, from three keys."""
    k_actor, k_critic, k_temp = keys
    actor_def = GaussianPolicy(
        make_encoder(config),
        config.hidden_dims,
        ex_act.shape[-1],
        tanh_squash=True,
        log_std_min=config.log_std_min,
        log_std_max=config.log_std_max,
    )
    critic_def = sac_critic(config, critic_dropout)
    return (
        make_train_state(actor_def, k_actor, (ex_obs,), config.actor_lr),
        make_train_state(critic_def, k_critic, (ex_obs, ex_act), config.critic_lr),
        make_train_state(Temperature(config.init_temperature), k_temp, (), config.temp_lr),
    )


def sac_critic(config: Config, critic_dropout: float | None = None, num_qs: int | None = None):
    """The critic ensemble module of :func:`sac_train_states` (``num_qs`` members; default ``config.num_qs``)."""
    return Critic(
        make_encoder(config),
        config.hidden_dims,
        config.num_qs if num_qs is None else num_qs,
        config.critic_layer_norm,
        critic_dropout,
    )


def split_utd(batch, utd: int):
    """Reshape every leaf (U·B, ...) → (U, B, ...)."""
    return jax.tree_util.tree_map(lambda x: x.reshape((utd, x.shape[0] // utd) + x.shape[1:]), batch)


def prepare_example(example_observations, example_actions):
    """Make example inputs batched numpy arrays (a single observation gets a batch axis of 1)."""
    ex_obs = jax.tree_util.tree_map(np.asarray, example_observations)
    ex_act = np.asarray(example_actions, dtype=np.float32)
    if ex_act.ndim == 1:
        ex_act = ex_act[None]
        ex_obs = jax.tree_util.tree_map(lambda x: x[None], ex_obs)
    return ex_obs, ex_act


def copy_tree(tree):
    """A copy with fresh buffers (target networks must not alias the online ones: buffers get donated)."""
    return jax.tree_util.tree_map(lambda x: jnp.array(x, copy=True), tree)
