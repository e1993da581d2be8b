"""Per-episode domains of the randomized kitchen, built with MjSpec (no XML string editing).

A :class:`Domain` holds discrete choices (microwave model, kettle model, light count) that change the
model's structure -- compiled once per choice and cached per process -- and continuous parameters
(texture colours, light directions/colours, camera jitter) written into the compiled model.
Microwave and kettle variants add *visual* shells/handles (no mass, no contacts), so the physics and
subtask checks stay those of the standard kitchen.  The kettle's start position gets +-3 cm noise;
the microwave is moved by +-1 cm and turned by 0-3 deg on the counter (the demonstrator reads the
handle's pose from the simulation, so it follows).  These ranges are small because the scripted
operator's door swing runs into the arm's reach beyond them: at +-3 cm / +-8 deg it opened the
microwave in about half of the corner cases we tried, at +-1 cm / 0-3 deg in 63 of 64.
"""

from __future__ import annotations

import dataclasses
import functools

import mujoco
import numpy as np

from d5rl.envs.kitchen import model as km

NUM_MICROWAVES = 4
NUM_KETTLES = 8
MAX_EXTRA_LIGHTS = 3
KETTLE_NOISE = 0.03  # m, uniform kettle start-position noise in x and y
MICROWAVE_NOISE = 0.01  # m, uniform microwave position noise in x and y (its counter frame)
MICROWAVE_YAW = (0.0, float(np.deg2rad(3.0)))  # rad, uniform microwave yaw range (towards the robot)
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
    colors: tuple  # rgba per recoloured material group
    lights: tuple  # (dir xyz, diffuse rgb) per extra light
    camera: tuple  # per side camera: (d lookat xyz, d distance, d azimuth deg, d elevation deg)
    kettle_offset: tuple = (0.0, 0.0)  # (dx, dy) m of the kettle's start position on its burner
    microwave_pose: tuple = (0.0, 0.0, 0.0)  # (dx, dy) m and yaw rad of the microwave on the counter

    @classmethod
    def sample(cls, rng: np.random.Generator) -> "Domain":
        mw, kt, nl = int(rng.integers(NUM_MICROWAVES)), int(rng.integers(NUM_KETTLES)), int(rng.integers(1, MAX_EXTRA_LIGHTS + 1))
        colors = tuple(tuple(float(x) for x in np.r_[rng.uniform(0.1, 0.9, 3), 1.0]) for _ in range(len(COLOR_GROUPS)))
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
        offset = tuple(float(x) for x in rng.uniform(-KETTLE_NOISE, KETTLE_NOISE, 2))
        mw_pose = (*(float(x) for x in rng.uniform(-MICROWAVE_NOISE, MICROWAVE_NOISE, 2)),
                   float(rng.uniform(*MICROWAVE_YAW)))
        return cls(mw, kt, nl, colors, tuple(lights), camera, offset, mw_pose)

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, d: dict) -> "Domain":
        def tup(x):
            return tuple(tup(v) for v in x) if isinstance(x, (list, tuple)) else x

        return cls(**{k: tup(v) for k, v in d.items()})


# material-name substrings recoloured together (cabinets, counter, floor/walls)
COLOR_GROUPS = ("hinge_wood", "counter_marble", "wall_white", "matplane")


def _add_microwave_variant(spec: mujoco.MjSpec, k: int) -> None:
    """Visual shell and handle of microwave model ``k`` (0 = the stock one)."""
    if k == 0:
        return
    body, door = spec.body("microroot"), spec.body("microdoorroot")
    rgba = [np.array([0.2, 0.2, 0.2, 1]), np.array([0.8, 0.8, 0.8, 1]), np.array([0.6, 0.1, 0.1, 1])][k - 1]
    half = [(0.23, 0.2, 0.17), (0.26, 0.18, 0.19), (0.22, 0.21, 0.15)][k - 1]
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=half, pos=(0, 0, half[2] - 0.02), rgba=rgba,
                  contype=0, conaffinity=0, group=1, name=f"mw_shell{k}")
    if k == 1:  # bar handle
        door.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=(0.32, -0.05, -0.12, 0.32, -0.05, 0.12),
                      size=(0.012, 0, 0), rgba=(0.9, 0.9, 0.9, 1), contype=0, conaffinity=0, group=1)
    elif k == 2:  # box handle
        door.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=(0.015, 0.02, 0.1), pos=(0.3, -0.04, 0),
                      rgba=(0.1, 0.1, 0.1, 1), contype=0, conaffinity=0, group=1)
    else:  # knob-like cylinder handle
        door.add_geom(type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=(0.03, 0.02, 0), pos=(0.3, -0.05, 0.05),
                      quat=(0.7071, 0.7071, 0, 0), rgba=(0.8, 0.7, 0.1, 1), contype=0, conaffinity=0, group=1)


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
    mw = model.body("microroot").id
    dx, dy, yaw = domain.microwave_pose
    model.body_pos[mw] = base.body_pos[mw] + (dx, dy, 0.0)
    turn = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
    mujoco.mju_mulQuat(model.body_quat[mw], base.body_quat[mw], turn)
    for group, rgba in zip(COLOR_GROUPS, domain.colors):
        for i in range(model.nmat):
            if group in model.material(i).name.lower():
                model.mat_rgba[i] = rgba
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


def domain_model(domain: Domain) -> mujoco.MjModel:
    model = compiled_variant(domain.microwave, domain.kettle, domain.num_lights).__copy__()
    apply_domain(model, domain)
    return model
