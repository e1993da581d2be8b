"""The WidowX scene's per-episode domain: which shoe and toy, and how the scene looks (table, floor
and wall textures and tints, object colours, light position, colour and brightness, ambient light,
camera pose), drawn from a seeded generator and applied to a compiled model."""

from __future__ import annotations

import dataclasses
from typing import Any

import mujoco
import numpy as np

from d5rl.envs.widowx.model import CATEGORY, POOL, SHOES, TOYS
from d5rl.envs.widowx.tabletop import KEY_LIGHT_POS, SIDE_CAMERA, SURFACE_TEXTURES, lookat_quat, texture_name
from d5rl.errors import DatasetVersionError

# Per-episode ranges (the paper: "textures, lighting conditions, and camera angles are also varied
# across episodes"; its figure shows small changes of viewpoint).
CAMERA_POS_JITTER = (0.04, 0.06, 0.04)  # m, uniform +- per axis
CAMERA_LOOKAT_JITTER = (0.02, 0.03, 0.02)
CAMERA_FOVY_JITTER = 3.0  # degrees
KEY_LIGHT_JITTER = (0.4, 0.4, 0.2)


@dataclasses.dataclass(frozen=True)
class Domain:
    """Everything that varies between episodes besides the simulator state (JSON-able)."""

    shoe: str
    toy: str
    table_texture: str
    table_rgb: tuple[float, float, float]
    floor_texture: str
    floor_rgb: tuple[float, float, float]
    wall_texture: str
    wall_rgb: tuple[float, float, float]
    bin_rgb: tuple[float, float, float]
    shoe_rgb: tuple[float, float, float]
    shoe_sole_rgb: tuple[float, float, float]
    toy_rgb: tuple[float, float, float]
    key_light_pos: tuple[float, float, float]
    key_light_rgb: tuple[float, float, float]
    fill_light_rgb: tuple[float, float, float]
    ambient: float
    camera_pos: tuple[float, float, float]
    camera_lookat: tuple[float, float, float]
    camera_fovy: float

    def to_json(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Domain:
        fields = {f.name for f in dataclasses.fields(cls)}
        if set(d) != fields:
            raise DatasetVersionError(
                f"this WidowX episode's domain differs from the current scene's in fields {sorted(set(d) ^ fields)}: "
                "it comes from an older dataset version",
                "regenerate the dataset with `d5rl generate TASK --force`",
            )
        return cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items()})

    @property
    def objects(self) -> tuple[str, str]:
        return (self.shoe, self.toy)


def _r(x) -> tuple[float, ...]:
    return tuple(round(float(v), 6) for v in x)


def _tint(u, lo: float, spread: float) -> tuple[float, ...]:
    """A colour near grey level ``u(lo, 1)`` with a small per-channel tint (warm, cool or neutral)."""
    level = u(lo, 1.0)
    return _r(np.clip(level * (1.0 + u(-spread, spread, 3)), 0.0, 1.0))


def sample_domain(rng: np.random.Generator, randomize: bool = True, shoes=SHOES, toys=TOYS) -> Domain:
    """Draw one shoe, one toy and (if ``randomize``) textures, lights and camera jitter."""
    shoe = str(shoes[rng.integers(len(shoes))])
    toy = str(toys[rng.integers(len(toys))])
    first = {k: v[0] for k, v in SURFACE_TEXTURES.items()}
    if not randomize:
        return Domain(
            shoe,
            toy,
            first["table"],
            (1.0, 1.0, 1.0),
            first["floor"],
            (1.0, 1.0, 1.0),
            first["wall"],
            (1.0, 1.0, 1.0),
            (0.92, 0.92, 0.92),
            (0.2, 0.3, 0.7),
            (0.95, 0.95, 0.95),
            (0.95, 0.8, 0.1),
            KEY_LIGHT_POS,
            (0.6, 0.6, 0.6),
            (0.3, 0.3, 0.3),
            0.25,
            SIDE_CAMERA["pos"],
            SIDE_CAMERA["lookat"],
            SIDE_CAMERA["fovy"],
        )
    u = rng.uniform

    def pick(surface: str) -> str:
        options = SURFACE_TEXTURES[surface]
        return str(options[rng.integers(len(options))])

    cam = np.asarray(SIDE_CAMERA["pos"]) + u(-1, 1, 3) * np.array(CAMERA_POS_JITTER)
    look = np.asarray(SIDE_CAMERA["lookat"]) + u(-1, 1, 3) * np.array(CAMERA_LOOKAT_JITTER)
    return Domain(
        shoe=shoe,
        toy=toy,
        table_texture=pick("table"),
        table_rgb=_tint(u, 0.6, 0.12),
        floor_texture=pick("floor"),
        floor_rgb=_tint(u, 0.5, 0.15),
        wall_texture=pick("wall"),
        wall_rgb=_r(u(0.45, 1.0, 3)),
        bin_rgb=_r(np.full(3, u(0.8, 1.0)) - u(0, 0.08, 3)),
        shoe_rgb=_r(u(0.05, 0.95, 3)),
        shoe_sole_rgb=_r(np.full(3, u(0.1, 1.0))),
        toy_rgb=_r(u(0.1, 1.0, 3)),
        key_light_pos=_r(np.asarray(KEY_LIGHT_POS) + u(-1, 1, 3) * np.array(KEY_LIGHT_JITTER)),
        key_light_rgb=_tint(u, 0.4, 0.15),  # brightness x a warm / cool colour temperature
        fill_light_rgb=_r(np.full(3, u(0.1, 0.45))),
        ambient=round(float(u(0.12, 0.35)), 6),
        camera_pos=_r(cam),
        camera_lookat=_r(look),
        camera_fovy=round(float(SIDE_CAMERA["fovy"] + u(-1, 1) * CAMERA_FOVY_JITTER), 6),
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

    for surface, name, color in (
        ("table", domain.table_texture, domain.table_rgb),
        ("floor", domain.floor_texture, domain.floor_rgb),
        ("wall", domain.wall_texture, domain.wall_rgb),
    ):
        if name not in SURFACE_TEXTURES[surface]:
            raise ValueError(f"unknown {surface} texture {name!r}; one of {SURFACE_TEXTURES[surface]}")
        model.mat_texid[mat(surface), rgb] = -1 if name == "plain" else tex(texture_name(name))
        model.mat_rgba[mat(surface)] = [*color, 1.0]
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
    model.light_diffuse[key] = domain.key_light_rgb
    model.light_diffuse[model.light("fill").id] = domain.fill_light_rgb
    model.vis.headlight.ambient[:] = domain.ambient
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
