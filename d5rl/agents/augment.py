"""DrQ image augmentation for pixel observations, in JAX.

* random shift (Kostrikov et al. 2020): pad by 4 pixels (edge replication) and
  crop back to the original size at a random offset, per sample;
* colour jitter: random brightness, contrast, saturation and hue per sample,
  the same for every stacked frame of a sample, applied with probability ``p``
  (as one affine colour map per sample and frame).

Images are uint8 ``(B, H, W, 3·stack)`` and stay uint8.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from d5rl.agents.encoders import pixel_keys


def random_shift(key, imgs, pad: int = 4):
    """Per-sample random translation by up to ``pad`` pixels (edge padding)."""
    b, h, w, _ = imgs.shape
    padded = jnp.pad(imgs, ((0, 0), (pad, pad), (pad, pad), (0, 0)), mode="edge")
    offsets = jax.random.randint(key, (b, 2), 0, 2 * pad + 1)

    def crop(img, off):
        return jax.lax.dynamic_slice(img, (off[0], off[1], 0), (h, w, img.shape[-1]))

    return jax.vmap(crop)(padded, offsets)


# numpy constants: a module-level jnp array would start a JAX backend on import, and processes that only
# import agents (the bench parent) would then hold an accelerator's memory (see tests/runner).
_RGB_TO_YIQ_64 = np.array([[0.299, 0.587, 0.114], [0.596, -0.274, -0.322], [0.211, -0.523, 0.312]])
_RGB_TO_YIQ = _RGB_TO_YIQ_64.astype(np.float32)
_YIQ_TO_RGB = np.linalg.inv(_RGB_TO_YIQ_64).astype(np.float32)
_LUMA = _RGB_TO_YIQ[0]  # Rec. 601 luma weights; they sum to 1


def jitter_params(key, batch: int, brightness=0.2, contrast=0.2, saturation=0.2, hue=0.05, p=0.8):
    """Each sample's colour jitter as the affine map ``A @ rgb + off·mean_luma`` (see
    :func:`color_jitter`): ``A`` of shape (batch, 3, 3) and ``off`` of shape (batch,)."""
    kb, kc, ks, kh, kp = jax.random.split(key, 5)
    fb = jax.random.uniform(kb, (batch,), minval=1 - brightness, maxval=1 + brightness)
    fc = jax.random.uniform(kc, (batch,), minval=1 - contrast, maxval=1 + contrast)
    fs = jax.random.uniform(ks, (batch,), minval=1 - saturation, maxval=1 + saturation)
    theta = jax.random.uniform(kh, (batch,), minval=-hue, maxval=hue) * 2 * jnp.pi
    apply = jax.random.uniform(kp, (batch,)) < p

    cos, sin = jnp.cos(theta), jnp.sin(theta)
    zero, one = jnp.zeros_like(cos), jnp.ones_like(cos)
    rot = jnp.stack(
        [jnp.stack([one, zero, zero], -1), jnp.stack([zero, cos, -sin], -1), jnp.stack([zero, sin, cos], -1)], -2
    )  # (b, 3, 3)
    hue_m = jnp.einsum("ij,bjk,kl->bil", _YIQ_TO_RGB, rot, _RGB_TO_YIQ)
    sat_m = fs[:, None, None] * jnp.eye(3) + (1 - fs)[:, None, None] * _LUMA[None, None, :]
    a = jnp.where(apply[:, None, None], (fc * fb)[:, None, None] * (hue_m @ sat_m), jnp.eye(3))
    return a, jnp.where(apply, (1 - fc) * fb, 0.0)


def apply_jitter(imgs, a, off):
    """Apply per-frame affine colour maps to uint8 ``(B, H, W, 3·F)``: ``a`` (B, F, 3, 3), ``off`` (B, F).
    Written on separate R, G, B planes: XLA:CPU is slow on a length-3 minor axis."""
    b, h, w, c = imgs.shape
    x = imgs.astype(jnp.float32).reshape(b, h, w, c // 3, 3)
    planes = [x[..., i] for i in range(3)]  # (b, h, w, frames) each, in [0, 255]
    luma = _LUMA[0] * planes[0] + _LUMA[1] * planes[1] + _LUMA[2] * planes[2]
    offset = (off * luma.mean(axis=(1, 2)))[:, None, None, :]  # off × the frame's mean luma
    a = a[:, None, None]  # (b, 1, 1, frames, 3, 3)
    y = [a[..., d, 0] * planes[0] + a[..., d, 1] * planes[1] + a[..., d, 2] * planes[2] + offset for d in range(3)]
    return jnp.clip(jnp.round(jnp.stack(y, axis=-1)), 0, 255).astype(jnp.uint8).reshape(b, h, w, c)


def color_jitter(key, imgs, brightness=0.2, contrast=0.2, saturation=0.2, hue=0.05, p=0.8):
    """Random brightness, contrast, saturation and hue (a rotation in YIQ space) per sample, the
    same for every stacked frame of a sample; a sample is jittered with probability ``p``.

    The four steps are, in this order, ``x*fb``; ``(x - mean)*fc + mean`` (mean luma of the frame);
    ``(x - luma)*fs + luma``; a hue rotation. None clips in between, so together they are one affine
    map per sample and frame, ``A @ rgb + c``: applied here as that map (3 multiply-adds per value
    instead of ~20). ``A = fc·fb·H·S`` with the hue matrix ``H`` and the saturation matrix ``S``; the
    offset is ``(1 - fc)·fb·mean`` on every channel because grey stays grey under ``H`` and ``S``.
    """
    return apply_jitter(imgs, *_frame_maps(key, imgs, brightness, contrast, saturation, hue, p))


def _frame_maps(key, imgs, *jitter_args):
    """:func:`jitter_params` for ``imgs``' samples, repeated for each of its stacked frames."""
    a, off = jitter_params(key, imgs.shape[0], *jitter_args)
    frames = imgs.shape[-1] // 3
    return jnp.repeat(a[:, None], frames, 1), jnp.repeat(off[:, None], frames, 1)


def augment_observations(key, obs, shift_pad: int = 4, jitter: bool = True):
    """Augment every ``pixels*`` array of a dict observation; other inputs pass through.

    Each camera gets its own shift and jitter (the same as :func:`random_shift` and
    :func:`color_jitter` with its key). The jitter runs once over all cameras concatenated on
    channels, each frame with its camera's map. The encoder concatenates the cameras the same way,
    and XLA:CPU fused separately jittered cameras into that concatenation as a slow loop: timed
    alone, augmentation + concatenation take 9 instead of 32 ms (two 64×64×9 cameras, batch 64).
    """
    keys = pixel_keys(obs)
    if not keys:
        return obs
    out = dict(obs)
    jittered, maps, offs = [], [], []
    for i, k in enumerate(keys):
        k1, k2 = jax.random.split(jax.random.fold_in(key, i))
        img = obs[k]
        if shift_pad:
            img = random_shift(k1, img, shift_pad)
        out[k] = img
        if jitter and img.shape[-1] % 3 == 0:
            a, off = _frame_maps(k2, img)
            jittered.append(k)
            maps.append(a)
            offs.append(off)
    if jittered:
        x = apply_jitter(
            jnp.concatenate([out[k] for k in jittered], -1), jnp.concatenate(maps, 1), jnp.concatenate(offs, 1)
        )
        start = 0
        for k in jittered:
            c = out[k].shape[-1]
            out[k] = x[..., start : start + c]
            start += c
    return out


def augment_batch(key, batch, config):
    """Augment ``observations`` and ``next_observations`` independently (DrQ) when the config asks."""
    if not pixel_keys(batch["observations"]) or not config.augment:
        return batch
    k1, k2 = jax.random.split(key)
    pad, jitter = int(config.shift_pad), bool(config.color_jitter)
    return {
        **batch,
        "observations": augment_observations(k1, batch["observations"], pad, jitter),
        "next_observations": augment_observations(k2, batch["next_observations"], pad, jitter),
    }
