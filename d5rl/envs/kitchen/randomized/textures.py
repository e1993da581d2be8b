"""Procedural surface textures for the randomized kitchen.

A fixed pool of patterns (wood grain, marble, tiles, terrazzo, brushed metal, cloudy noise,
stripes, checker) is added to every compiled scene variant as cube textures (one face repeated:
the kitchen's meshes have no UV coordinates, so MuJoCo maps cube textures onto them by
direction).  Each pattern is a grey-level image in [FLOOR, 1] drawn from a fixed seed, so every
machine builds the same pixels; a domain picks one pattern per surface group and tints it with
the material's colour (MuJoCo multiplies texture and ``rgba``).  Switching patterns is a write
to ``model.mat_texid``: all textures are uploaded when a renderer is made, no recompiling.
"""

from __future__ import annotations

from typing import Callable

import mujoco
import numpy as np

SIZE = 128  # texels per cube face
FLOOR = 0.35  # darkest grey level: tints stay visible in the dark parts of a pattern
_SEED = 20240607  # fixed: the pool is part of the env definition, not of a domain


def _grid(size: int) -> tuple[np.ndarray, np.ndarray]:
    y, x = np.mgrid[0:size, 0:size] / size
    return x, y


def _smooth_noise(rng: np.random.Generator, size: int, cells: int) -> np.ndarray:
    """Value noise: a random ``cells`` x ``cells`` lattice bilinearly interpolated (tiles seamlessly)."""
    lattice = rng.random((cells, cells))
    u = np.arange(size) * cells / size
    i0 = np.floor(u).astype(int)
    f = u - i0
    f = f * f * (3 - 2 * f)  # smoothstep: no visible lattice creases
    i1 = (i0 + 1) % cells
    rows = lattice[i0][:, i0] * (1 - f)[None, :] + lattice[i0][:, i1] * f[None, :]
    rows1 = lattice[i1][:, i0] * (1 - f)[None, :] + lattice[i1][:, i1] * f[None, :]
    return rows * (1 - f)[:, None] + rows1 * f[:, None]


def _fbm(rng: np.random.Generator, size: int, octaves: int = 4, base: int = 4) -> np.ndarray:
    out = sum(_smooth_noise(rng, size, base * 2**o) / 2**o for o in range(octaves))
    return (out - out.min()) / (np.ptp(out) + 1e-9)


def wood(rng, size):
    x, y = _grid(size)
    rings = np.sin(2 * np.pi * (9 * x + 1.5 * _fbm(rng, size)))
    return 0.55 + 0.3 * rings + 0.15 * _smooth_noise(rng, size, 64)


def marble(rng, size):
    x, y = _grid(size)
    return np.abs(np.sin(2 * np.pi * (2 * (x + y) + 2.5 * _fbm(rng, size, octaves=5)))) ** 0.4


def tiles(rng, size, n: int = 4):
    x, y = _grid(size)
    shade = 0.8 + 0.2 * rng.random((n, n))
    out = shade[(y * n).astype(int), (x * n).astype(int)]
    grout = (np.minimum((x * n) % 1, (y * n) % 1) < 0.06)
    return np.where(grout, 0.0, out)


def terrazzo(rng, size):
    base = 0.75 + 0.1 * _fbm(rng, size)
    chips = _smooth_noise(rng, size, 32) > 0.8
    dark = _smooth_noise(rng, size, 24) < 0.15
    return np.where(chips, 1.0, np.where(dark, 0.1, base))


def brushed(rng, size):
    streaks = rng.random(size)[:, None] * np.ones((1, size))
    return 0.7 + 0.2 * streaks + 0.1 * _smooth_noise(rng, size, 8)


def clouds(rng, size):
    return _fbm(rng, size, octaves=5, base=2)


def stripes(rng, size, n: int = 6):
    x, _ = _grid(size)
    return np.where((x * n) % 1 < 0.5, 1.0, 0.3)


def checker(rng, size, n: int = 4):
    x, y = _grid(size)
    return np.where(((x * n).astype(int) + (y * n).astype(int)) % 2 == 0, 1.0, 0.2)


PATTERNS: dict[str, Callable[[np.random.Generator, int], np.ndarray]] = {
    "wood": wood,
    "marble": marble,
    "tiles": tiles,
    "terrazzo": terrazzo,
    "brushed": brushed,
    "clouds": clouds,
    "stripes": stripes,
    "checker": checker,
}
NAMES: tuple[str, ...] = tuple(PATTERNS)


def texture_name(pattern: str) -> str:
    return f"rand_tex_{pattern}"


def pattern_image(pattern: str, size: int = SIZE) -> np.ndarray:
    """uint8 (size, size, 3) grey image of ``pattern`` (the same on every machine)."""
    rng = np.random.default_rng([_SEED, NAMES.index(pattern)])
    g = np.clip(PATTERNS[pattern](rng, size), 0.0, 1.0)
    g = FLOOR + (1.0 - FLOOR) * g
    return np.repeat((255 * g).round().astype(np.uint8)[..., None], 3, axis=-1)


def add_textures(spec: mujoco.MjSpec) -> None:
    """Add the whole pattern pool to ``spec`` as cube textures."""
    for name in NAMES:
        tex = spec.add_texture(name=texture_name(name), type=mujoco.mjtTexture.mjTEXTURE_CUBE,
                               width=SIZE, height=SIZE, nchannel=3)
        tex.data = pattern_image(name).tobytes()
