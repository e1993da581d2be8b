"""Per-episode domains of the randomized kitchen, built with MjSpec (no XML string editing).

A :class:`Domain` holds discrete choices (microwave model, kettle model) that change the model's
structure -- compiled per choice -- and parameters (surface textures, tints and scales, how many of
the extra lights are on and their directions/colours, camera jitter, object poses) written into the
compiled model or the start state.  A compiled variant is ~40 MB (mostly the stock textures), so only
the few arrays :func:`apply_domain` resets from are kept per variant; environments keep their own
copies (see ``RandomizedKitchenEnv.set_domain``).

- Objects (:mod:`.objects`): 4 microwave and 8 kettle models, each with its own collision geometry,
  mass and handle, and the grasp plan the operator uses for it (``RandomizedKitchenEnv.grasp_plans``).
- Poses: the kettle starts on one of two burners (bottom left, as in the standard kitchen, or
  top right: KitchenShift-style two sites) plus noise of :data:`KETTLE_X` / :data:`KETTLE_Y` and a yaw
  within :data:`KETTLE_YAW`; the microwave moves by :data:`MICROWAVE_X` / :data:`MICROWAVE_Y` on the
  counter and turns by :data:`MICROWAVE_YAW`.  Each range was measured against the skilled
  operator's success at its corners (data card).
- Looks: surface groups (cabinet panels, metal fronts, cabinet handles, counter top, walls, floor)
  each get a photograph (:mod:`.textures`) at one of two scales, the stock texture or none, tinted
  per domain; 1-3 extra lights; jitter of the two side cameras.

Subtask checks stay those of the standard kitchen.  ``quality="high"`` compiles the same scene with
the stock render settings (shadows, reflections, multisampling, full meshes) for figures and
videos; physics is identical, only the pictures change.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from d5rl.envs.kitchen import model as km
from d5rl.envs.kitchen.randomized import objects, textures
from d5rl.envs.kitchen.randomized.objects import NUM_KETTLES, NUM_MICROWAVES
from d5rl.errors import D5RLError

MAX_EXTRA_LIGHTS = 3
# Kettle start sites: (dx, dy) m of the kettle from its stock pose (on the bottom-left burner).
# bottom left and top right (burner centres: 0.446 m apart in x, 0.44 in y).  Not the bottom-right
# burner: right in front of the robot's base, the arm reaches it only with its base joint near its
# limit and cannot carry the kettle over to the left (0 of 24 at the range's corners).  The centre of
# the top-right burner rather than its front (4 cm closer): 3.66 objects per demo episode against 3.63
# (the same 32 episodes).
KETTLE_SITES = ((0.0, 0.0), (0.446, 0.44))
# m, uniform kettle start-position noise at its site in x and y (+y: away from the robot).  Closer to the
# robot than 1 cm the stock kettle's scripted grasp starts with the shoulder at its limit.
KETTLE_X = (-0.03, 0.03)
KETTLE_Y = (-0.01, 0.03)
KETTLE_YAW = float(np.deg2rad(20.0))  # rad, uniform kettle yaw about its vertical axis (+-)
MICROWAVE_X = (-0.05, 0.03)  # m, uniform microwave offset along the counter (its frame's x; - is further left)
MICROWAVE_Y = (-0.03, 0.04)  # m, towards / away from the wall
MICROWAVE_YAW = (0.0, float(np.deg2rad(10.0)))  # rad, uniform microwave yaw range (towards the robot)
CAMERA_NAMES = ("left", "right")
QUALITIES = ("fast", "high")
# Side cameras (two views from the robot's left and right), jittered per episode.
SIDE_CAMERAS = {
    "left": km.LookAtCamera(lookat=(-0.3, 0.6, 2.0), distance=2.2, azimuth=60.0, elevation=-35.0, fovy=50.0),
    "right": km.LookAtCamera(lookat=(-0.1, 0.6, 2.0), distance=2.2, azimuth=120.0, elevation=-35.0, fovy=50.0),
}

# materials re-textured and recoloured together (the visible surfaces of the scene), and the skins a
# group may get: "photo@scale" (see textures.NAMES), "stock" (the material's own texture), "plain" (colour only)
SURFACES = {
    "cabinet panels": ("M_hinge_blue", "M_slide_blue", "counter_blue", "wall_blue"),
    "metal fronts": ("oven_metal", "counter_metal"),
    "cabinet handles": ("M_slide_metal", "M_hinge_metal"),
    "counter top": ("counter_marble",),
    "walls": ("wall_white",),
    "floor": ("MatPlane",),
}
SKINS = {
    "cabinet panels": ("wood@1", "wood@2", "marble@1", "metal@1", "white-tile@1", "plain", "stock"),
    "metal fronts": ("metal@1", "metal@2", "wood@1", "plain", "stock"),
    "cabinet handles": ("metal@1", "metal@2", "wood@2", "plain", "stock"),
    "counter top": ("marble@1", "marble@2", "tile@1", "tile@2", "marble-tile@1", "white-tile@2", "wood@1", "stock"),
    "walls": ("tile@1", "tile@2", "marble-tile@1", "marble-tile@2", "white-tile@1", "marble@1", "plain"),
    "floor": ("wood@1", "wood@2", "tile@1", "tile@2", "marble-tile@1", "white-tile@1", "stock"),
}
FLAT = ("MatPlane",)  # materials on planes: 2D textures (a repeat count per domain), the rest cube-mapped
FLOOR_REPEAT = 4.0  # the stock floor's texture repeat; a skin's scale multiplies it


def _tint(rng: np.random.Generator, skin: str) -> tuple:
    """A colour for a surface: a random colour for a plain one, a light tint of random hue for a
    photograph (MuJoCo multiplies them: strong colours would hide the photo)."""
    if skin == "plain":
        rgb = rng.uniform(0.1, 0.9, 3)
    else:
        rgb = rng.uniform(0.75, 1.0) * (1.0 - rng.uniform(0.0, 0.35) * rng.random(3))
    return tuple(float(x) for x in np.r_[rgb, 1.0])


@dataclasses.dataclass(frozen=True)
class Domain:
    microwave: int
    kettle: int
    num_lights: int
    colors: tuple  # rgba per surface group (SURFACES order); multiplies the group's texture
    lights: tuple  # (dir xyz, diffuse rgb) per extra light
    camera: tuple  # per side camera: (d lookat xyz, d distance, d azimuth deg, d elevation deg)
    kettle_offset: tuple = (0.0, 0.0)  # (dx, dy) m of the kettle's start position at its site
    microwave_pose: tuple = (0.0, 0.0, 0.0)  # (dx, dy) m and yaw rad of the microwave on the counter
    textures: tuple = ()  # per surface group: one of its SKINS
    kettle_yaw: float = 0.0  # rad, the kettle's start yaw about its vertical axis
    kettle_site: int = 0  # index into KETTLE_SITES

    @classmethod
    def sample(cls, rng: np.random.Generator) -> Domain:
        mw, kt, nl = (
            int(rng.integers(NUM_MICROWAVES)),
            int(rng.integers(NUM_KETTLES)),
            int(rng.integers(1, MAX_EXTRA_LIGHTS + 1)),
        )
        skins = tuple(SKINS[g][int(rng.integers(len(SKINS[g])))] for g in SURFACES)
        colors = tuple(_tint(rng, skin) for skin in skins)
        lights = []
        for _ in range(nl):
            d = rng.normal(size=3)
            d[2] = -abs(d[2]) - 0.5
            d /= np.linalg.norm(d)
            lights.append((tuple(float(x) for x in d), tuple(float(x) for x in rng.uniform(0.2, 0.6, 3))))
        camera = tuple(
            (
                tuple(float(x) for x in rng.normal(0, 0.05, 3)),
                float(rng.normal(0, 0.05)),
                float(rng.normal(0, 1.0)),
                float(rng.normal(0, 1.0)),
            )
            for _ in CAMERA_NAMES
        )
        site = int(rng.integers(len(KETTLE_SITES)))
        offset = (float(rng.uniform(*KETTLE_X)), float(rng.uniform(*KETTLE_Y)))
        mw_pose = (
            float(rng.uniform(*MICROWAVE_X)),
            float(rng.uniform(*MICROWAVE_Y)),
            float(rng.uniform(*MICROWAVE_YAW)),
        )
        kettle_yaw = float(rng.uniform(-KETTLE_YAW, KETTLE_YAW))
        return cls(mw, kt, nl, colors, tuple(lights), camera, offset, mw_pose, skins, kettle_yaw, site)

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, d: dict) -> Domain:
        def tup(x):
            return tuple(tup(v) for v in x) if isinstance(x, (list, tuple)) else x

        stale = D5RLError(
            "this domain was recorded by an older version of the randomized kitchen "
            "(other surface groups, textures or object models)",
            "regenerate the dataset with `d5rl generate` (its generator version is stale)",
        )
        try:
            domain = cls(**{k: tup(v) for k, v in d.items()})
        except TypeError:
            raise stale from None
        if (
            len(domain.colors) != len(SURFACES)
            or len(domain.textures) != len(SURFACES)
            or any(s not in SKINS[g] for g, s in zip(SURFACES, domain.textures))
        ):
            raise stale
        return domain

    @property
    def key(self) -> tuple[int, int]:
        """The discrete choices that need their own compiled model."""
        return (self.microwave, self.kettle)


def _add_extra_lights(spec: mujoco.MjSpec, n: int, shadows: bool) -> None:
    # all of them in every variant; a domain switches off those it does not use (``light_active``)
    for i in range(n):
        spec.worldbody.add_light(
            name=f"rand_light{i}", pos=(0, 0.5, 4.0), dir=(0, 0, -1), castshadow=shadows, diffuse=(0.3, 0.3, 0.3)
        )


def _add_side_cameras(spec: mujoco.MjSpec) -> None:
    for name, cam in SIDE_CAMERAS.items():
        pos, xyaxes = cam.pose()
        c = spec.worldbody.add_camera(name=name, pos=pos, fovy=cam.fovy)
        c.alt.type = mujoco.mjtOrientation.mjORIENTATION_XYAXES
        c.alt.xyaxes = xyaxes


def compiled_variant(microwave: int, kettle: int, quality: str = "fast") -> mujoco.MjModel:
    """The compiled kitchen for one discrete choice (a new model on every call, ~0.8 s)."""
    high = quality == "high"
    spec = km.build_spec(km.SceneOptions(fast_render=False, decimate_cell=None) if high else km.SceneOptions())
    textures.add_textures(spec)
    _add_side_cameras(spec)
    objects.add_microwave(spec, microwave)
    objects.add_kettle(spec, kettle)
    _add_extra_lights(spec, MAX_EXTRA_LIGHTS, shadows=high)
    model = spec.compile()
    _base_arrays(microwave, kettle, quality, model)
    return model


_BASE: dict[tuple, dict[str, np.ndarray]] = {}


def _base_arrays(microwave: int, kettle: int, quality: str, model: mujoco.MjModel | None = None) -> dict:
    """The arrays of a freshly compiled variant that :func:`apply_domain` writes from (kB, kept per process)."""
    key = (microwave, kettle, quality)
    if key not in _BASE:
        m = model if model is not None else compiled_variant(microwave, kettle, quality)
        mw = m.body("microroot").id
        _BASE[key] = {
            "mat_rgba": m.mat_rgba.copy(),
            "mat_texid": m.mat_texid.copy(),
            "mat_texrepeat": m.mat_texrepeat.copy(),
            "microwave_pos": m.body_pos[mw].copy(),
            "microwave_quat": m.body_quat[mw].copy(),
        }
    return _BASE[key]


def _camera_quat(xyaxes: np.ndarray) -> np.ndarray:
    right, up = xyaxes[:3], xyaxes[3:]
    z = np.cross(right, up)
    mat = np.stack([right, up, z], axis=1).ravel()
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, mat)
    return q


def apply_domain(model: mujoco.MjModel, domain: Domain, quality: str = "fast") -> None:
    """Write the continuous parameters of ``domain`` into a compiled variant (in place)."""
    base = _base_arrays(*domain.key, quality)
    model.mat_rgba[:] = base["mat_rgba"]
    model.mat_texid[:] = base["mat_texid"]
    model.mat_texrepeat[:] = base["mat_texrepeat"]
    mw = model.body("microroot").id
    dx, dy, yaw = domain.microwave_pose
    model.body_pos[mw] = base["microwave_pos"] + (dx, dy, 0.0)
    turn = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
    mujoco.mju_mulQuat(model.body_quat[mw], base["microwave_quat"], turn)
    for materials, rgba, skin in zip(SURFACES.values(), domain.colors, domain.textures, strict=True):
        for name in materials:
            i = model.material(name).id
            model.mat_rgba[i] = rgba
            if skin == "plain":
                model.mat_texid[i, mujoco.mjtTextureRole.mjTEXROLE_RGB] = -1
            elif skin != "stock":
                flat = name in FLAT
                model.mat_texid[i, mujoco.mjtTextureRole.mjTEXROLE_RGB] = model.texture(
                    textures.texture_name(skin, flat)
                ).id
                if flat:
                    model.mat_texrepeat[i] = FLOOR_REPEAT * int(skin.split("@")[1])
    for i in range(MAX_EXTRA_LIGHTS):
        model.light_active[model.light(f"rand_light{i}").id] = i < len(domain.lights)
    for i, (d, diffuse) in enumerate(domain.lights):
        lid = model.light(f"rand_light{i}").id
        model.light_dir[lid] = d
        model.light_diffuse[lid] = diffuse
    for name, (dlook, ddist, daz, del_) in zip(CAMERA_NAMES, domain.camera):
        cam = SIDE_CAMERAS[name]
        jit = km.LookAtCamera(
            tuple(np.add(cam.lookat, dlook)), cam.distance + ddist, cam.azimuth + daz, cam.elevation + del_, cam.fovy
        )
        pos, xyaxes = jit.pose()
        cid = model.camera(name).id
        model.cam_pos[cid] = pos
        model.cam_quat[cid] = _camera_quat(xyaxes)


def grasp_plans(domain: Domain) -> dict:
    """The operator's grasp plan per subtask for this domain's object models."""
    return {"kettle": objects.kettle_grasp(domain.kettle), "microwave": objects.microwave_grasp(domain.microwave)}


def kettle_start_offset(domain: Domain) -> tuple[float, float]:
    """(dx, dy) m of the kettle's start position from the stock one: its site plus the noise."""
    sx, sy = KETTLE_SITES[domain.kettle_site]
    return (sx + domain.kettle_offset[0], sy + domain.kettle_offset[1])
