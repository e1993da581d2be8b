"""Photographic surface textures for the randomized kitchen.

The images are the kitchen asset package's own photographs (``gymnasium-robotics``, Apache-2.0,
``kitchen_franka/kitchen_assets/textures``: wood, marble, brushed metal, ceramic tiles and two
white marble tilings), read from the extracted wheel (:mod:`d5rl.assets`; nothing is downloaded
at run time).  Each photo is added to every compiled scene variant at two scales -- the photo
resized to :data:`SIZE` texels ("1x") and a 2 x 2 tiling of it ("2x", a finer grain) -- as cube
textures (the kitchen's meshes have no UV coordinates, so MuJoCo maps cube textures onto them by
direction, as the stock scene does) and, for the floor plane, as 2D textures whose repeat count a
domain sets.  A domain picks a photo and a scale per surface group and tints it with the
material's colour (MuJoCo multiplies texture and ``rgba``).  Switching is a write to
``model.mat_texid`` / ``mat_texrepeat``: all textures are uploaded when a renderer is made.
"""

from __future__ import annotations

import functools

import mujoco
import numpy as np

from d5rl.envs.kitchen.model import asset_dir

SIZE = 256  # texels per side (the photos are 512-1300 px; software rendering samples 128 px frames)
# name -> file in kitchen_assets/textures
PHOTOS = {
    "wood": "wood1.png",
    "marble": "marble1.png",
    "metal": "metal1.png",
    "tile": "tile1.png",
    "marble-tile": "white_marble_tile.png",
    "white-tile": "white_marble_tile2.png",
}
SCALES = (1, 2)
NAMES: tuple[str, ...] = tuple(f"{p}@{s}" for p in PHOTOS for s in SCALES)  # cube textures: "wood@2"


def texture_name(skin: str, flat: bool = False) -> str:
    photo, scale = skin.split("@")
    return f"rand_{'2d' if flat else 'cube'}_{photo}_{scale}"


@functools.cache
def photo_image(photo: str, scale: int = 1, size: int = SIZE) -> np.ndarray:
    """uint8 (size, size, 3): the photo resized to ``size / scale`` and tiled ``scale`` x ``scale``."""
    from PIL import Image

    path = asset_dir() / "kitchen_assets" / "textures" / PHOTOS[photo]
    with Image.open(path) as im:
        cell = size // scale
        img = np.asarray(im.convert("RGB").resize((cell, cell), Image.Resampling.LANCZOS), dtype=np.uint8)
    return np.tile(img, (scale, scale, 1))


def add_textures(spec: mujoco.MjSpec) -> None:
    """Add every photo at every scale to ``spec``: cube textures, and 2D ones for the floor."""
    for skin in NAMES:
        photo, scale = skin.split("@")
        data = photo_image(photo, int(scale)).tobytes()
        for flat in (False, True):
            kind = mujoco.mjtTexture.mjTEXTURE_2D if flat else mujoco.mjtTexture.mjTEXTURE_CUBE
            tex = spec.add_texture(name=texture_name(skin, flat), type=kind, width=SIZE, height=SIZE, nchannel=3)
            tex.data = data
