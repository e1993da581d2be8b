"""The WidowX scene's per-episode domain: which shoe and toy, and how the scene looks (textures,
colours, lights, camera pose), drawn from a seeded generator and applied to a compiled model."""

from __future__ import annotations

import dataclasses
from typing import Any

import mujoco
import numpy as np

from d5rl.envs.widowx.model import (CATEGORY, NUM_FLOOR_TEXTURES, NUM_TABLE_TEXTURES, POOL, SHOES, SIDE_CAMERA, TOYS,
                                    lookat_quat)


@dataclasses.dataclass(frozen=True)
class Domain:
    """Everything that varies between episodes besides the simulator state (JSON-able)."""

    shoe: str
    toy: str
    table_texture: int
    table_rgb: tuple[float, float, float]
    floor_texture: int
    floor_rgb: tuple[float, float, float]
    bin_rgb: tuple[float, float, float]
    shoe_rgb: tuple[float, float, float]
    shoe_sole_rgb: tuple[float, float, float]
    toy_rgb: tuple[float, float, float]
    key_light_pos: tuple[float, float, float]
    key_light_diffuse: float
    fill_light_diffuse: float
    camera_pos: tuple[float, float, float]
    camera_lookat: tuple[float, float, float]
    camera_fovy: float

    def to_json(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "Domain":
        return cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items()})

    @property
    def objects(self) -> tuple[str, str]:
        return (self.shoe, self.toy)


def _r(x) -> tuple[float, ...]:
    return tuple(round(float(v), 6) for v in x)


def sample_domain(rng: np.random.Generator, randomize: bool = True, shoes=SHOES, toys=TOYS) -> Domain:
    """Draw one shoe, one toy and (if ``randomize``) textures, lights and camera jitter."""
    shoe = str(shoes[rng.integers(len(shoes))])
    toy = str(toys[rng.integers(len(toys))])
    if not randomize:
        return Domain(shoe, toy, 0, (1.0, 1.0, 1.0), 0, (1.0, 1.0, 1.0), (0.92, 0.92, 0.92), (0.2, 0.3, 0.7),
                      (0.95, 0.95, 0.95), (0.95, 0.8, 0.1), (0.3, -0.5, 1.2), 0.6, 0.3,
                      SIDE_CAMERA["pos"], SIDE_CAMERA["lookat"], SIDE_CAMERA["fovy"])
    u = rng.uniform
    cam = np.asarray(SIDE_CAMERA["pos"]) + u(-1, 1, 3) * np.array([0.04, 0.06, 0.04])
    look = np.asarray(SIDE_CAMERA["lookat"]) + u(-1, 1, 3) * np.array([0.02, 0.03, 0.02])
    return Domain(
        shoe=shoe,
        toy=toy,
        table_texture=int(rng.integers(NUM_TABLE_TEXTURES)),
        table_rgb=_r(u(0.6, 1.0, 3)),
        floor_texture=int(rng.integers(NUM_FLOOR_TEXTURES)),
        floor_rgb=_r(u(0.4, 1.0, 3)),
        bin_rgb=_r(np.full(3, u(0.8, 1.0)) - u(0, 0.08, 3)),
        shoe_rgb=_r(u(0.05, 0.95, 3)),
        shoe_sole_rgb=_r(np.full(3, u(0.1, 1.0))),
        toy_rgb=_r(u(0.1, 1.0, 3)),
        key_light_pos=_r(np.array([0.3, -0.5, 1.2]) + u(-1, 1, 3) * np.array([0.4, 0.4, 0.2])),
        key_light_diffuse=round(float(u(0.4, 0.8)), 6),
        fill_light_diffuse=round(float(u(0.15, 0.45)), 6),
        camera_pos=_r(cam),
        camera_lookat=_r(look),
        camera_fovy=round(float(SIDE_CAMERA["fovy"] + u(-3, 3)), 6),
    )


def apply_domain(model: mujoco.MjModel, domain: Domain) -> None:
    """Set the episode's looks on a compiled model and park the objects not drawn.

    Only model fields are edited (materials, lights, camera, contact flags of the
    parked objects), so this is cheap and exactly repeatable from ``meta``.
    """
    rgb = int(mujoco.mjtTextureRole.mjTEXROLE_RGB)

    def mat(name):
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_MATERIAL, name)

    def tex(name):
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXTURE, name)

    model.mat_texid[mat("table"), rgb] = tex(f"table_tex{domain.table_texture}")
    model.mat_rgba[mat("table")] = [*domain.table_rgb, 1.0]
    model.mat_texid[mat("floor"), rgb] = tex(f"floor_tex{domain.floor_texture}")
    model.mat_rgba[mat("floor")] = [*domain.floor_rgb, 1.0]
    model.mat_rgba[mat("bin")] = [*domain.bin_rgb, 1.0]
    for name in POOL:
        color = domain.toy_rgb if CATEGORY[name] == "toy" else domain.shoe_rgb
        model.mat_rgba[mat(f"{name}_upper")] = [*color, 1.0]
        if CATEGORY[name] == "shoe":
            model.mat_rgba[mat(f"{name}_sole")] = [*domain.shoe_sole_rgb, 1.0]
    key = model.light("key").id
    model.light_pos[key] = domain.key_light_pos
    d = np.array([0.3, 0.0, 0.0]) - np.asarray(domain.key_light_pos)
    model.light_dir[key] = d / np.linalg.norm(d)
    model.light_diffuse[key] = domain.key_light_diffuse
    model.light_diffuse[model.light("fill").id] = domain.fill_light_diffuse
    cam = model.camera("side").id
    model.cam_pos[cam] = domain.camera_pos
    model.cam_quat[cam] = lookat_quat(domain.camera_pos, domain.camera_lookat)
    model.cam_fovy[cam] = domain.camera_fovy
    active = set(domain.objects)
    for name in POOL:
        b = model.body(name).id
        on = name in active
        geoms = np.flatnonzero(model.geom_bodyid == b)
        for g in geoms:
            # toys collide through their convex pieces (the visual mesh is group 2), shoes through all parts
            collides = on and model.geom_group[g] != 2
            model.geom_contype[g] = int(collides)
            model.geom_conaffinity[g] = int(collides)
        model.body_gravcomp[b] = 0.0 if on else 1.0
