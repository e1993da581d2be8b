"""Per-episode domains of the randomized kitchen, built with MjSpec (no XML string editing).

A :class:`Domain` holds discrete choices (microwave model, kettle model, light count) that change the
model's structure -- compiled once per choice and cached per process -- and continuous parameters
(surface textures and colours, light directions/colours, camera jitter) written into the compiled model.
Surfaces come in groups (cabinet panels, metal fronts, counter top, walls, floor); each group gets a
pattern from :mod:`.textures` (or the stock texture, or none) tinted with a random colour.
Microwave and kettle variants add *visual* shells (no mass, no contacts); each microwave model also
moves and resizes the door's handle (visual and collision geometry and the grasp site), so the handle
in the images is the one the robot pulls.  Subtask checks stay those of the standard kitchen.  The kettle's start position moves by +-3 cm
in x and -1..+3 cm in y and it turns by +-15 deg; the microwave by +-3 cm in x and y and 0-8 deg in
yaw on the counter (the demonstrator reads handle poses from the simulation, so it follows).
Measured with the skilled operator on the stock microwave alone: 48 of 48 at four corners of the
range (12 domains each; at the corner +4 cm, -4 cm, 12 deg: 3 of 8 within 250 steps); the other
models' handles at the corners: see the data card.
"""

from __future__ import annotations

import dataclasses
import functools

import mujoco
import numpy as np

from d5rl.envs.kitchen import model as km
from d5rl.envs.kitchen.randomized import textures

NUM_MICROWAVES = 4
NUM_KETTLES = 8
MAX_EXTRA_LIGHTS = 3
# m, uniform kettle start-position offsets in x and in y (+y: away from the robot).  Closer to the
# robot than 1 cm the scripted grasp starts with the shoulder at its limit and the carry stalls
# (kettle alone, 12 domains each: dy -0.03: 0, -0.02: 1, -0.015: 6, -0.01: 11, 0: 11, +0.03: 10).
KETTLE_X = (-0.03, 0.03)
KETTLE_Y = (-0.01, 0.03)
# rad, uniform kettle yaw about its vertical axis (kettle alone at +-15 and +-25 deg: 12 of 12 each;
# after the slide cabinet: 11 of 12 at 0, 10 at +15, 8 at +25 deg)
KETTLE_YAW = float(np.deg2rad(15.0))
MICROWAVE_NOISE = 0.03  # m, uniform microwave position noise in x and y (its counter frame)
MICROWAVE_YAW = (0.0, float(np.deg2rad(8.0)))  # rad, uniform microwave yaw range (towards the robot)
CAMERA_NAMES = ("left", "right")
# Side cameras (two views from the robot's left and right), jittered per episode.
SIDE_CAMERAS = {
    "left": km.LookAtCamera(lookat=(-0.3, 0.6, 2.0), distance=2.2, azimuth=60.0, elevation=-35.0, fovy=50.0),
    "right": km.LookAtCamera(lookat=(-0.1, 0.6, 2.0), distance=2.2, azimuth=120.0, elevation=-35.0, fovy=50.0),
}


@dataclasses.dataclass(frozen=True)
class Domain:
    microwave: int
    kettle: int
    num_lights: int
    colors: tuple  # rgba per surface group (SURFACES order); multiplies the group's texture
    lights: tuple  # (dir xyz, diffuse rgb) per extra light
    camera: tuple  # per side camera: (d lookat xyz, d distance, d azimuth deg, d elevation deg)
    kettle_offset: tuple = (0.0, 0.0)  # (dx, dy) m of the kettle's start position on its burner
    microwave_pose: tuple = (0.0, 0.0, 0.0)  # (dx, dy) m and yaw rad of the microwave on the counter
    textures: tuple = ()  # per surface group: a pattern of `textures.NAMES`, "stock" or "plain"
    kettle_yaw: float = 0.0  # rad, the kettle's start yaw about its vertical axis

    @classmethod
    def sample(cls, rng: np.random.Generator) -> "Domain":
        mw, kt, nl = int(rng.integers(NUM_MICROWAVES)), int(rng.integers(NUM_KETTLES)), int(rng.integers(1, MAX_EXTRA_LIGHTS + 1))
        colors = tuple(tuple(float(x) for x in np.r_[rng.uniform(0.1, 0.9, 3), 1.0]) for _ in SURFACES)
        lights = []
        for _ in range(nl):
            d = rng.normal(size=3)
            d[2] = -abs(d[2]) - 0.5
            d /= np.linalg.norm(d)
            lights.append((tuple(float(x) for x in d), tuple(float(x) for x in rng.uniform(0.2, 0.6, 3))))
        camera = tuple(
            (tuple(float(x) for x in rng.normal(0, 0.05, 3)), float(rng.normal(0, 0.05)),
             float(rng.normal(0, 1.0)), float(rng.normal(0, 1.0)))
            for _ in CAMERA_NAMES
        )
        offset = (float(rng.uniform(*KETTLE_X)), float(rng.uniform(*KETTLE_Y)))
        mw_pose = (*(float(x) for x in rng.uniform(-MICROWAVE_NOISE, MICROWAVE_NOISE, 2)),
                   float(rng.uniform(*MICROWAVE_YAW)))
        skins = tuple(TEXTURE_CHOICES[int(rng.integers(len(TEXTURE_CHOICES)))] for _ in SURFACES)
        kettle_yaw = float(rng.uniform(-KETTLE_YAW, KETTLE_YAW))
        return cls(mw, kt, nl, colors, tuple(lights), camera, offset, mw_pose, skins, kettle_yaw)

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, d: dict) -> "Domain":
        def tup(x):
            return tuple(tup(v) for v in x) if isinstance(x, (list, tuple)) else x

        domain = cls(**{k: tup(v) for k, v in d.items()})
        if len(domain.colors) != len(SURFACES) or len(domain.textures) != len(SURFACES):
            from d5rl.errors import D5RLError

            raise D5RLError("this domain was recorded by an older version of the randomized kitchen "
                            f"({len(domain.colors)} surface groups, this version has {len(SURFACES)})",
                            "regenerate the dataset with `d5rl generate` (its generator version is stale)")
        return domain


# materials re-textured and recoloured together (the visible surfaces of the scene)
SURFACES = {
    "cabinet panels": ("M_hinge_blue", "M_slide_blue", "counter_blue", "wall_blue"),
    "metal fronts": ("oven_metal", "counter_metal", "M_slide_metal", "M_hinge_metal"),
    "counter top": ("counter_marble",),
    "walls": ("wall_white",),
    "floor": ("MatPlane",),
}
# "stock": the material's own texture (if any); "plain": no texture, colour only
TEXTURE_CHOICES = ("stock", "plain", *textures.NAMES)


# Door handles of the microwave models: (position along the door from its hinge, half-length of the
# vertical bar, bar radius) in m.  The stock handle is (0.475, 0.13, 0.02).
MICROWAVE_HANDLES = {1: (0.455, 0.17, 0.018), 2: (0.445, 0.09, 0.024), 3: (0.47, 0.08, 0.022)}
HANDLE_COLORS = {1: (0.9, 0.9, 0.9, 1), 2: (0.1, 0.1, 0.1, 1), 3: (0.8, 0.7, 0.1, 1)}


def _add_microwave_variant(spec: mujoco.MjSpec, k: int) -> None:
    """Microwave model ``k`` (0 = the stock one): a visual shell of its own shape and colour, and its
    own door handle -- the stock handle's visual and collision capsules (and the site the operator
    grasps) moved along the door and resized, so the handle the robot pulls is the one in the images."""
    if k == 0:
        return
    body, door = spec.body("microroot"), spec.body("microdoorroot")
    rgba = [np.array([0.2, 0.2, 0.2, 1]), np.array([0.8, 0.8, 0.8, 1]), np.array([0.6, 0.1, 0.1, 1])][k - 1]
    half = [(0.23, 0.2, 0.17), (0.26, 0.18, 0.19), (0.22, 0.21, 0.15)][k - 1]
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=half, pos=(0, 0, half[2] - 0.02), rgba=rgba,
                  contype=0, conaffinity=0, group=1, name=f"mw_shell{k}")
    x, length, radius = MICROWAVE_HANDLES[k]
    stock_x = door.sites[0].pos[0]
    for g in door.geoms:
        if g.type != mujoco.mjtGeom.mjGEOM_CAPSULE or abs(g.pos[0] - stock_x) > 1e-6:
            continue
        bar = abs(g.pos[2]) < 1e-6  # the bar itself; the other two are its stand-offs at the ends
        g.pos = (x, g.pos[1], 0.0 if bar else np.sign(g.pos[2]) * length)
        g.size = (radius, length if bar else g.size[1], 0.0)
        if g.group == 1:
            g.rgba = HANDLE_COLORS[k]
    door.sites[0].pos = (x, door.sites[0].pos[1], door.sites[0].pos[2])


def _add_kettle_variant(spec: mujoco.MjSpec, k: int) -> None:
    """Visual body/handle of kettle model ``k`` (0 = the stock one): 4 body shapes x 2 handle shapes."""
    if k == 0:
        return
    body = spec.body("kettleroot")
    shape, handle = k % 4, k // 4
    rgba = (0.2 + 0.2 * shape, 0.3, 0.8 - 0.15 * shape, 1)
    kw = dict(contype=0, conaffinity=0, group=1, rgba=rgba)
    if shape == 0:
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_ELLIPSOID, size=(0.11, 0.11, 0.08), pos=(0, 0, 0.07), **kw)
    elif shape == 1:
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=(0.1, 0.07, 0), pos=(0, 0, 0.07), **kw)
    elif shape == 2:
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=(0.09, 0.09, 0.07), pos=(0, 0, 0.07), **kw)
    else:
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=(0.1, 0, 0), pos=(0, 0, 0.08), **kw)
    if handle:
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=(0.01, 0.07, 0.01), pos=(0, 0, 0.26),
                      contype=0, conaffinity=0, group=1, rgba=(0.1, 0.1, 0.1, 1))


def _add_extra_lights(spec: mujoco.MjSpec, n: int) -> None:
    for i in range(n):
        spec.worldbody.add_light(name=f"rand_light{i}", pos=(0, 0.5, 4.0), dir=(0, 0, -1), castshadow=False,
                                 diffuse=(0.3, 0.3, 0.3))


def _add_side_cameras(spec: mujoco.MjSpec) -> None:
    for name, cam in SIDE_CAMERAS.items():
        pos, xyaxes = cam.pose()
        c = spec.worldbody.add_camera(name=name, pos=pos, fovy=cam.fovy)
        c.alt.type = mujoco.mjtOrientation.mjORIENTATION_XYAXES
        c.alt.xyaxes = xyaxes


@functools.lru_cache(maxsize=32)
def compiled_variant(microwave: int, kettle: int, num_lights: int) -> mujoco.MjModel:
    """The compiled kitchen for one discrete choice (cached per process)."""
    spec = km.build_spec()
    textures.add_textures(spec)
    _add_side_cameras(spec)
    _add_microwave_variant(spec, microwave)
    _add_kettle_variant(spec, kettle)
    _add_extra_lights(spec, num_lights)
    return spec.compile()


def _camera_quat(xyaxes: np.ndarray) -> np.ndarray:
    right, up = xyaxes[:3], xyaxes[3:]
    z = np.cross(right, up)
    mat = np.stack([right, up, z], axis=1).ravel()
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, mat)
    return q


def apply_domain(model: mujoco.MjModel, domain: Domain) -> None:
    """Write the continuous parameters of ``domain`` into a compiled variant (in place)."""
    base = compiled_variant(domain.microwave, domain.kettle, domain.num_lights)
    model.mat_rgba[:] = base.mat_rgba
    model.mat_texid[:] = base.mat_texid
    mw = model.body("microroot").id
    dx, dy, yaw = domain.microwave_pose
    model.body_pos[mw] = base.body_pos[mw] + (dx, dy, 0.0)
    turn = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
    mujoco.mju_mulQuat(model.body_quat[mw], base.body_quat[mw], turn)
    skins = domain.textures or ("stock",) * len(SURFACES)
    for materials, rgba, skin in zip(SURFACES.values(), domain.colors, skins, strict=True):
        tex = {"stock": None, "plain": -1}.get(skin)
        if skin not in ("stock", "plain"):
            tex = model.texture(textures.texture_name(skin)).id
        for name in materials:
            i = model.material(name).id
            model.mat_rgba[i] = rgba
            if tex is not None:
                model.mat_texid[i, mujoco.mjtTextureRole.mjTEXROLE_RGB] = tex
    for i, (d, diffuse) in enumerate(domain.lights):
        lid = model.light(f"rand_light{i}").id
        model.light_dir[lid] = d
        model.light_diffuse[lid] = diffuse
    for name, (dlook, ddist, daz, del_) in zip(CAMERA_NAMES, domain.camera):
        cam = SIDE_CAMERAS[name]
        jit = km.LookAtCamera(tuple(np.add(cam.lookat, dlook)), cam.distance + ddist, cam.azimuth + daz,
                              cam.elevation + del_, cam.fovy)
        pos, xyaxes = jit.pose()
        cid = model.camera(name).id
        model.cam_pos[cid] = pos
        model.cam_quat[cid] = _camera_quat(xyaxes)
