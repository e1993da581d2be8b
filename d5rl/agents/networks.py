"""Networks shared by the agents: MLPs, critic ensembles, Gaussian and deterministic policies, the
SAC temperature.  Encoders: :mod:`d5rl.agents.encoders`; diffusion noise models:
:mod:`d5rl.agents.diffusion`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import flax
import flax.linen as nn
import jax
import jax.numpy as jnp

default_init = nn.initializers.variance_scaling(1.0, "fan_avg", "uniform")  # Glorot uniform


# --- MLPs ---------------------------------------------------------------------------------------
class MLP(nn.Module):
    """Dense layers with an activation (and optional LayerNorm / dropout) between them."""

    hidden_dims: Sequence[int]
    activation: Callable = nn.relu
    activate_final: bool = False
    layer_norm: bool = False
    dropout_rate: float | None = None

    @nn.compact
    def __call__(self, x, train: bool = False):
        for i, size in enumerate(self.hidden_dims):
            x = nn.Dense(size, kernel_init=default_init)(x)
            if i + 1 < len(self.hidden_dims) or self.activate_final:
                if self.dropout_rate:
                    x = nn.Dropout(self.dropout_rate)(x, deterministic=not train)
                if self.layer_norm:
                    x = nn.LayerNorm()(x)
                x = self.activation(x)
        return x


# --- critics ------------------------------------------------------------------------------------
class Ensemble(nn.Module):
    """``num`` independent copies of an MLP head with the same input, stacked on axis 0."""

    hidden_dims: Sequence[int]
    num: int
    layer_norm: bool = False
    dropout_rate: float | None = None

    @nn.compact
    def __call__(self, x, train: bool = False):
        vmapped = nn.vmap(
            MLP,
            variable_axes={"params": 0},
            split_rngs={"params": True, "dropout": True},
            in_axes=None,
            out_axes=0,
            axis_size=self.num,
        )
        out = vmapped(tuple(self.hidden_dims) + (1,), layer_norm=self.layer_norm, dropout_rate=self.dropout_rate)(
            x, train
        )
        return out[..., 0]


def ensemble_members(critic_params, index):
    """A :class:`Critic`'s params with only the ensemble members ``index`` (each head leaf is stacked on axis
    0; the shared encoder is kept whole): apply them with a ``Critic`` of ``num_qs=len(index)``."""
    params = dict(critic_params)
    params["heads"] = jax.tree_util.tree_map(lambda p: p[index], params["heads"])
    return params


class Critic(nn.Module):
    """Q(s, a) ensemble sharing one observation encoder: returns ``(num_qs, batch)``.

    ``encode`` and ``head`` split the call so that many actions per observation
    (CQL, IDQL) reuse one encoding.
    """

    encoder: nn.Module
    hidden_dims: Sequence[int]
    num_qs: int = 2
    layer_norm: bool = False
    dropout_rate: float | None = None

    def setup(self):
        self.heads = Ensemble(self.hidden_dims, self.num_qs, self.layer_norm, self.dropout_rate)

    def encode(self, obs):
        return self.encoder(obs)

    def head(self, features, actions, train: bool = False):
        return self.heads(jnp.concatenate([features, actions], axis=-1), train)

    def __call__(self, obs, actions, train: bool = False):
        return self.head(self.encode(obs), actions, train)


class ValueCritic(nn.Module):
    """V(s): returns ``(batch,)``."""

    encoder: nn.Module
    hidden_dims: Sequence[int]
    layer_norm: bool = False

    @nn.compact
    def __call__(self, obs, train: bool = False):
        h = self.encoder(obs)
        return MLP(tuple(self.hidden_dims) + (1,), layer_norm=self.layer_norm)(h)[..., 0]


# --- policies -----------------------------------------------------------------------------------
_LOG_2PI = math.log(2.0 * math.pi)


@flax.struct.dataclass
class Gaussian:
    """A diagonal Gaussian, optionally squashed by tanh.

    Without ``tanh`` the mean itself is tanh-bounded (IQL/BC style) and the
    log-likelihood is a plain Gaussian one; with ``tanh`` samples are squashed
    and the log-prob carries the change-of-variables term (SAC style).
    """

    loc: jax.Array
    log_std: jax.Array
    tanh: bool = flax.struct.field(pytree_node=False, default=True)

    def _normal_logp(self, u):
        z = (u - self.loc) * jnp.exp(-self.log_std)
        return jnp.sum(-0.5 * z**2 - self.log_std - 0.5 * _LOG_2PI, axis=-1)

    @staticmethod
    def _tanh_logdet(u):
        return jnp.sum(2.0 * (math.log(2.0) - u - jax.nn.softplus(-2.0 * u)), axis=-1)

    def sample_and_log_prob(self, key):
        eps = jax.random.normal(key, self.loc.shape)
        u = self.loc + jnp.exp(self.log_std) * eps
        logp = jnp.sum(-0.5 * eps**2 - self.log_std - 0.5 * _LOG_2PI, axis=-1)
        if self.tanh:
            return jnp.tanh(u), logp - self._tanh_logdet(u)
        return u, logp

    def sample(self, key):
        return self.sample_and_log_prob(key)[0]

    def sample_n_and_log_prob(self, key, n: int):
        """``n`` samples per distribution: shapes ``(n, *batch, A)`` and ``(n, *batch)``."""
        wide = Gaussian(
            jnp.broadcast_to(self.loc, (n,) + self.loc.shape),
            jnp.broadcast_to(self.log_std, (n,) + self.log_std.shape),
            self.tanh,
        )
        return wide.sample_and_log_prob(key)

    def log_prob(self, actions):
        if self.tanh:
            a = jnp.clip(actions, -1 + 1e-6, 1 - 1e-6)
            u = jnp.arctanh(a)
            return self._normal_logp(u) - self._tanh_logdet(u)
        return self._normal_logp(actions)

    def mode(self):
        return jnp.tanh(self.loc) if self.tanh else self.loc

    def entropy_estimate(self, key):
        return -self.sample_and_log_prob(key)[1]


class GaussianPolicy(nn.Module):
    """π(a|s) as a :class:`Gaussian`; state-dependent log-std clipped to [log_std_min, log_std_max], one learned
    log-std vector (``state_dependent_std=False``) or a fixed unit std (``fixed_std``)."""

    encoder: nn.Module
    hidden_dims: Sequence[int]
    action_dim: int
    tanh_squash: bool = True
    log_std_min: float = -5.0
    log_std_max: float = 2.0
    state_dependent_std: bool = True
    layer_norm: bool = False
    fixed_std: bool = False
    dropout_rate: float | None = None

    @nn.compact
    def __call__(self, obs, temperature: float = 1.0, train: bool = False):
        h = self.encoder(obs)
        h = MLP(self.hidden_dims, activate_final=True, layer_norm=self.layer_norm, dropout_rate=self.dropout_rate)(
            h, train
        )
        loc = nn.Dense(self.action_dim, kernel_init=default_init)(h)
        if self.fixed_std:
            log_std = jnp.zeros_like(loc)
        else:
            if self.state_dependent_std:
                log_std = nn.Dense(self.action_dim, kernel_init=default_init)(h)
            else:
                log_std = jnp.broadcast_to(self.param("log_std", nn.initializers.zeros, (self.action_dim,)), loc.shape)
            log_std = jnp.clip(log_std, self.log_std_min, self.log_std_max)
        log_std = log_std + jnp.log(temperature)
        if not self.tanh_squash:
            loc = jnp.tanh(loc)
        return Gaussian(loc, log_std, tanh=self.tanh_squash)


class DeterministicPolicy(nn.Module):
    """a = tanh(MLP(s)) (TD3), or with ``output="clip"`` the linear output clipped to [-1, 1] (the mean of
    jaxrl2's unit-std ``NormalPolicy``, which the D5RL release's pixel TD3+BC acts with)."""

    encoder: nn.Module
    hidden_dims: Sequence[int]
    action_dim: int
    layer_norm: bool = False
    output: str = "tanh"

    @nn.compact
    def __call__(self, obs, train: bool = False):
        h = self.encoder(obs)
        h = MLP(self.hidden_dims, activate_final=True, layer_norm=self.layer_norm)(h, train)
        out = nn.Dense(self.action_dim, kernel_init=default_init)(h)
        return jnp.clip(out, -1.0, 1.0) if self.output == "clip" else jnp.tanh(out)


class Temperature(nn.Module):
    """SAC's entropy temperature α = exp(log α)."""

    initial_value: float = 1.0

    @nn.compact
    def __call__(self):
        log_t = self.param("log_temp", lambda _: jnp.full((), math.log(self.initial_value), jnp.float32))
        return jnp.exp(log_t)


# --- helpers --------------------------------------------------------------------------------------
def soft_update(target: Any, online: Any, tau: float) -> Any:
    return jax.tree_util.tree_map(lambda t, o: t * (1 - tau) + o * tau, target, online)
