"""The LayerNorm-ResNet noise model of diffusion policies (IDQL) and its noise schedule."""

from __future__ import annotations

from collections.abc import Callable

import flax.linen as nn
import jax.numpy as jnp

from d5rl.agents.networks import MLP, default_init


class FourierFeatures(nn.Module):
    """Learnable Fourier features of the diffusion time (IDQL)."""

    output_size: int = 64

    @nn.compact
    def __call__(self, t):
        w = self.param("kernel", nn.initializers.normal(0.2), (self.output_size // 2, t.shape[-1]))
        f = 2 * jnp.pi * t @ w.T
        return jnp.concatenate([jnp.cos(f), jnp.sin(f)], axis=-1)


class ResidualBlock(nn.Module):
    """x + Dense(Dropout/LayerNorm → Dense(4·d) → act → Dense(d)) (IDQL's MLPResNetBlock)."""

    features: int
    activation: Callable = nn.swish
    dropout_rate: float | None = None
    layer_norm: bool = True

    @nn.compact
    def __call__(self, x, train: bool = False):
        residual = x
        if self.dropout_rate:
            x = nn.Dropout(self.dropout_rate)(x, deterministic=not train)
        if self.layer_norm:
            x = nn.LayerNorm()(x)
        x = nn.Dense(self.features * 4, kernel_init=default_init)(x)
        x = self.activation(x)
        x = nn.Dense(self.features, kernel_init=default_init)(x)
        return residual + x


class LNResNet(nn.Module):
    """IDQL's LayerNorm MLP-ResNet: Dense → blocks → act → Dense(out)."""

    num_blocks: int
    hidden_dim: int
    out_dim: int
    activation: Callable = nn.swish
    dropout_rate: float | None = 0.1
    layer_norm: bool = True

    @nn.compact
    def __call__(self, x, train: bool = False):
        x = nn.Dense(self.hidden_dim, kernel_init=default_init)(x)
        for _ in range(self.num_blocks):
            x = ResidualBlock(self.hidden_dim, self.activation, self.dropout_rate, self.layer_norm)(x, train)
        x = self.activation(x)
        return nn.Dense(self.out_dim, kernel_init=default_init)(x)


class DiffusionNoiseModel(nn.Module):
    """ε_θ(a_t, t | s): Fourier time features → MLP, concatenated with obs features and a_t.

    ``encode`` once, then ``denoise`` at every diffusion step.
    """

    encoder: nn.Module
    action_dim: int
    num_blocks: int = 3
    hidden_dim: int = 256
    time_dim: int = 64
    dropout_rate: float | None = 0.1

    def setup(self):
        self.time_features = FourierFeatures(self.time_dim)
        self.time_mlp = MLP((self.time_dim * 2, self.time_dim * 2), activation=nn.swish)
        self.net = LNResNet(self.num_blocks, self.hidden_dim, self.action_dim, dropout_rate=self.dropout_rate)

    def encode(self, obs):
        return self.encoder(obs)

    def denoise(self, features, noisy_actions, t, train: bool = False):
        te = self.time_mlp(self.time_features(t))
        return self.net(jnp.concatenate([features, noisy_actions, te], axis=-1), train)

    def __call__(self, obs, noisy_actions, t, train: bool = False):
        return self.denoise(self.encode(obs), noisy_actions, t, train)


def cosine_beta_schedule(num_steps: int, s: float = 0.008):
    """Nichol & Dhariwal (2021) cosine schedule, betas clipped to [0, 0.999]."""
    steps = num_steps + 1
    t = jnp.linspace(0, num_steps, steps) / num_steps
    alphas_cumprod = jnp.cos((t + s) / (1 + s) * jnp.pi * 0.5) ** 2
    alphas_cumprod = alphas_cumprod / alphas_cumprod[0]
    betas = 1 - alphas_cumprod[1:] / alphas_cumprod[:-1]
    return jnp.clip(betas, 0, 0.999)
