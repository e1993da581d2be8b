"""The WidowX scene's static tabletop: a table (top + four legs) that the robot and the bins stand
on, the floor and walls of a room around it, the surface textures, two lights and the side camera.

Textures
    Photographs of wood, marble, concrete and tiles from the kitchen assets that the pinned
    ``gymnasium-robotics`` wheel ships (``kitchen_franka/kitchen_assets/textures``, Apache-2.0;
    the same extracted assets the Franka kitchen uses), box-filtered to
    :data:`TEXTURE_SIZE` texels when the scene is built, plus one procedural plaster for the
    walls.  A domain (:mod:`d5rl.envs.widowx.domain`) picks one texture per surface (table,
    floor, walls) and a colour that tints it; switching is a write to ``model.mat_texid``, so the
    model is compiled once per process.
"""

from __future__ import annotations

import mujoco
import numpy as np

from d5rl.assets import asset_path

# Scene constants (metres; robot base at the origin, table top at z = 0)
TABLE_CENTER_X = 0.2
TABLE_HALF = (0.45, 0.55)
TABLE_THICKNESS = 0.04
TABLE_HEIGHT = 0.75  # the floor is this far below the table top
LEG_HALF = 0.025
BACK_WALL_X = -1.4  # the wall behind the robot, which the side camera looks at
SIDE_WALL_Y = 1.6
WALL_HEIGHT = 2.5
BIN_CENTERS = {"shoe": (0.30, 0.21), "toy": (0.30, -0.21)}
BIN_INNER_HALF = 0.075  # inner half-width of a bin (square)
BIN_WALL = 0.008  # wall thickness
BIN_HEIGHT = 0.06  # wall height
BIN_FLOOR = 0.006  # floor thickness

TEXTURE_SIZE = 256  # texels per side after filtering (the camera sees a table at ~100 px)
PHOTOS = ("wood1", "marble1", "metal1", "tile1", "white_marble_tile2")  # kitchen_assets/textures/*.png
# Surface -> the textures a domain may pick for it ("plaster": procedural; "plain": no texture).
SURFACE_TEXTURES = {
    "table": ("wood1", "marble1", "metal1", "white_marble_tile2", "plain"),
    "floor": ("tile1", "wood1", "white_marble_tile2", "metal1"),
    "wall": ("plaster", "marble1", "metal1", "plain"),
}
SIDE_CAMERA = dict(pos=(0.80, -0.02, 0.50), lookat=(0.24, 0.0, 0.02), fovy=50.0)
KEY_LIGHT_POS = (0.3, -0.5, 1.2)


def _photo(name: str) -> np.ndarray:
    """uint8 (TEXTURE_SIZE, TEXTURE_SIZE, 3): a kitchen texture photo, cropped square and box-filtered."""
    import imageio.v3 as iio  # a dependency of d5rl (reads PNG through pillow)

    path = asset_path(
        "gymnasium-robotics", "envs", "assets", "kitchen_franka", "kitchen_assets", "textures", f"{name}.png"
    )
    img = np.asarray(iio.imread(path))[..., :3].astype(np.float64)
    k = min(img.shape[:2]) // TEXTURE_SIZE
    img = img[: k * TEXTURE_SIZE, : k * TEXTURE_SIZE]
    img = img.reshape(TEXTURE_SIZE, k, TEXTURE_SIZE, k, 3).mean(axis=(1, 3))
    return np.clip(img.round(), 0, 255).astype(np.uint8)


def _plaster() -> np.ndarray:
    """A light, slightly mottled wall texture (fixed seed: the same texels on every machine)."""
    rng = np.random.default_rng(20261124)
    n = TEXTURE_SIZE
    u = np.arange(n) * 8 / n
    i0 = np.floor(u).astype(int)
    f = u - i0
    lattice = rng.random((8, 8))
    i1 = (i0 + 1) % 8
    rows = lattice[i0][:, i0] * (1 - f) + lattice[i0][:, i1] * f
    rows1 = lattice[i1][:, i0] * (1 - f) + lattice[i1][:, i1] * f
    mottle = rows * (1 - f)[:, None] + rows1 * f[:, None]
    g = 0.86 + 0.08 * mottle + 0.03 * rng.random((n, n))
    return np.repeat((255 * np.clip(g, 0, 1)).round().astype(np.uint8)[..., None], 3, axis=-1)


def texture_images() -> dict[str, np.ndarray]:
    """Every texture of the pool by name."""
    out = {name: _photo(name) for name in PHOTOS}
    out["plaster"] = _plaster()
    return out


def texture_name(name: str) -> str:
    return f"surface_{name}"


def _add_textures(spec: mujoco.MjSpec) -> None:
    for name, img in texture_images().items():
        t = spec.add_texture(
            name=texture_name(name),
            type=mujoco.mjtTexture.mjTEXTURE_2D,
            width=img.shape[1],
            height=img.shape[0],
            nchannel=3,
        )
        t.data = img.tobytes()
    rgb = mujoco.mjtTextureRole.mjTEXROLE_RGB
    for surface, repeat in (("table", (2, 2)), ("floor", (8, 8)), ("wall", (4, 2))):
        m = spec.add_material(name=surface, texrepeat=list(repeat), texuniform=False, specular=0.1, reflectance=0.0)
        m.textures[rgb] = texture_name(SURFACE_TEXTURES[surface][0])
    spec.add_material(name="table_leg", rgba=[0.25, 0.22, 0.2, 1.0], specular=0.1)
    spec.add_material(name="bin", rgba=[0.92, 0.92, 0.92, 1.0], specular=0.2, reflectance=0.0)


def box(body, name, half, pos, material=None, rgba=None, **kw):
    g = body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_BOX, size=list(half), pos=list(pos), **kw)
    if material:
        g.material = material
    if rgba is not None:
        g.rgba = list(rgba)
    return g


def _add_bin(spec: mujoco.MjSpec, name: str, center: tuple[float, float]) -> None:
    """An open box from five boxes (floor + four walls) – a single mesh would be convex and hold nothing."""
    b = spec.worldbody.add_body(name=f"{name}_bin", pos=[center[0], center[1], 0.0])
    h, w, t = BIN_INNER_HALF, BIN_WALL, BIN_FLOOR
    outer = h + w
    kw = dict(material="bin", friction=[0.8, 0.01, 0.001], condim=3)
    box(b, f"{name}_bin_floor", (outer, outer, t / 2), (0, 0, t / 2), **kw)
    zc = t + BIN_HEIGHT / 2
    box(b, f"{name}_bin_wall_px", (w / 2, outer, BIN_HEIGHT / 2), (h + w / 2, 0, zc), **kw)
    box(b, f"{name}_bin_wall_nx", (w / 2, outer, BIN_HEIGHT / 2), (-h - w / 2, 0, zc), **kw)
    box(b, f"{name}_bin_wall_py", (h, w / 2, BIN_HEIGHT / 2), (0, h + w / 2, zc), **kw)
    box(b, f"{name}_bin_wall_ny", (h, w / 2, BIN_HEIGHT / 2), (0, -h - w / 2, zc), **kw)


def add_tabletop(spec: mujoco.MjSpec) -> None:
    """Room, table, bins, lights and the side camera (the robot's base stands on the table at the origin)."""
    _add_textures(spec)
    wb = spec.worldbody
    # The room holds what falls off the table: floor, walls and legs collide, so a toy thrown off the table
    # lands on the floor.
    floor_z = -TABLE_HEIGHT
    wb.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[3, 3, 0.1], pos=[0, 0, floor_z], material="floor")
    mid_z = floor_z + WALL_HEIGHT / 2
    box(wb, "wall_back", (0.01, SIDE_WALL_Y, WALL_HEIGHT / 2), (BACK_WALL_X - 0.01, 0, mid_z), material="wall")
    for sign, side in ((1, "left"), (-1, "right")):
        box(
            wb,
            f"wall_{side}",
            (1.5, 0.01, WALL_HEIGHT / 2),
            (BACK_WALL_X + 1.5, sign * (SIDE_WALL_Y + 0.01), mid_z),
            material="wall",
        )
    hx, hy = TABLE_HALF
    box(
        wb,
        "table",
        (hx, hy, TABLE_THICKNESS / 2),
        (TABLE_CENTER_X, 0.0, -TABLE_THICKNESS / 2),
        material="table",
        friction=[0.8, 0.01, 0.001],
        condim=3,
    )
    leg_h = (TABLE_HEIGHT - TABLE_THICKNESS) / 2
    for sx in (-1, 1):
        for sy in (-1, 1):
            pos = (TABLE_CENTER_X + sx * (hx - 0.06), sy * (hy - 0.06), floor_z + leg_h)
            box(
                wb,
                f"table_leg_{'f' if sx > 0 else 'b'}{'l' if sy > 0 else 'r'}",
                (LEG_HALF, LEG_HALF, leg_h),
                pos,
                material="table_leg",
            )
    for k, c in BIN_CENTERS.items():
        _add_bin(spec, k, c)
    wb.add_light(
        name="key",
        pos=list(KEY_LIGHT_POS),
        dir=[0.0, 0.4, -1.0],
        diffuse=[0.6, 0.6, 0.6],
        castshadow=False,
        type=mujoco.mjtLightType.mjLIGHT_SPOT,
        cutoff=60.0,
    )
    wb.add_light(
        name="fill",
        pos=[0.6, 0.6, 1.0],
        dir=[-0.4, -0.6, -1.0],
        diffuse=[0.3, 0.3, 0.3],
        castshadow=False,
        type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
    )
    wb.add_camera(
        name="side",
        pos=list(SIDE_CAMERA["pos"]),
        fovy=SIDE_CAMERA["fovy"],
        quat=list(lookat_quat(SIDE_CAMERA["pos"], SIDE_CAMERA["lookat"])),
    )


def lookat_quat(pos, lookat) -> np.ndarray:
    """Camera quaternion looking from ``pos`` at ``lookat`` with the image's up towards +z."""
    pos, lookat = np.asarray(pos, float), np.asarray(lookat, float)
    back = pos - lookat
    back /= np.linalg.norm(back)  # camera z axis points away from the scene
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    mat = np.stack([right, up, back], axis=1)
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, mat.flatten())
    return q
