"""The Franka Kitchen scene, built with MjSpec from the relay-policy-learning assets.

The MJCF files come from the ``gymnasium-robotics`` wheel
(``gymnasium_robotics/envs/assets/kitchen_franka``, Apache-2.0).  We only use the
assets: the scene is loaded into an :class:`mujoco.MjSpec`, then edited in code:

- an ``overview`` camera (the LEXA-style view that frames the robot and every
  object) and a ``wrist`` camera on the hand are added;
- render settings are made cheap for software rendering (no shadows, no
  reflections, no MSAA, a small offscreen buffer) and the robot's visual meshes
  (134k of the scene's 142k triangles) are decimated by vertex clustering.

Physics is untouched by the render edits (visual meshes have no mass and no
contacts), so a state stored with one setting replays identically with another.
The randomized kitchen builds on :func:`build_spec` / :class:`SceneOptions`.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from pathlib import Path

import mujoco
import numpy as np

from d5rl.assets import asset_path

ROBOT_JOINTS = (
    "robot:panda0_joint1",
    "robot:panda0_joint2",
    "robot:panda0_joint3",
    "robot:panda0_joint4",
    "robot:panda0_joint5",
    "robot:panda0_joint6",
    "robot:panda0_joint7",
    "robot:panda0_finger_joint1",
    "robot:panda0_finger_joint2",
)
NUM_ROBOT_QPOS = 9
NUM_OBJECT_QPOS = 21  # 4 knobs + 4 burners, light switch + light, slide, 2 hinges, microwave, kettle (7)
END_EFFECTOR_SITE = "end_effector"
HAND_BODY = "panda0_link7"

# The kitchen's rest pose (D4RL's/gymnasium-robotics' initial qpos, robot then objects).
INIT_QPOS = np.array(
    [
        1.48388023e-01, -1.76848573e00, 1.84390296e00, -2.47685760e00, 2.60252026e-01, 7.12533105e-01,
        1.59515394e00, 4.79267505e-02, 3.71350919e-02, -2.66279850e-04, -5.18043486e-05, 3.12877220e-05,
        -4.51199853e-05, -3.90842156e-06, -4.22629655e-05, 6.28065475e-05, 4.04984708e-05, 4.62730939e-04,
        -2.26906415e-04, -4.65501369e-04, -6.44129196e-03, -1.77048263e-03, 1.08009684e-03, -2.69397440e-01,
        3.50383255e-01, 1.61944683e00, 1.00618764e00, 4.06395120e-03, -6.62095997e-03, -2.68278933e-04,
    ]
)  # fmt: skip


def asset_dir() -> Path:
    """``kitchen_franka`` of the ``gymnasium-robotics`` wheel (see :mod:`d5rl.assets`)."""
    path = asset_path("gymnasium-robotics", "envs", "assets", "kitchen_franka")
    asset_path("gymnasium-robotics", "envs", "assets", "kitchen_franka", "kitchen_assets", "kitchen_env_model.xml")
    return path


# --- cameras -----------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class LookAtCamera:
    """A fixed camera given like MuJoCo's free camera: look-at point, distance, azimuth, elevation (deg)."""

    lookat: tuple[float, float, float]
    distance: float
    azimuth: float
    elevation: float
    fovy: float = 45.0

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """World position and ``xyaxes`` (camera right and up vectors) of the camera."""
        az, el = np.deg2rad(self.azimuth), np.deg2rad(self.elevation)
        forward = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        pos = np.asarray(self.lookat, dtype=float) - self.distance * forward
        right = np.array([np.sin(az), -np.cos(az), 0.0])
        up = np.cross(right, forward)
        return pos, np.concatenate([right, up])


# LEXA-style view from behind and above the robot (LEXA: distance 1.86, look-at (-0.3, 0.5, 2.0),
# azimuth 90), pulled back and lowered so both wall cabinets, the microwave, the kettle, the knobs,
# the light switch and the whole arm are in frame.
OVERVIEW_CAMERA = LookAtCamera(lookat=(-0.2, 0.6, 2.1), distance=2.3, azimuth=90.0, elevation=-40.0, fovy=50.0)


@dataclasses.dataclass(frozen=True)
class WristCamera:
    """A camera on the hand (frame of ``panda0_link7``), looking along the gripper between the fingers."""

    pos: tuple[float, float, float] = (0.05, -0.05, 0.11)  # beside the hand, off the finger axis
    target: tuple[float, float, float] = (0.0, 0.0, 0.25)  # a point just ahead of the fingertips
    fovy: float = 80.0

    def xyaxes(self) -> np.ndarray:
        forward = np.asarray(self.target, dtype=float) - np.asarray(self.pos, dtype=float)
        forward /= np.linalg.norm(forward)
        up_hint = np.array([1.0, -1.0, 0.0]) / np.sqrt(2)  # from the palm towards the camera
        right = np.cross(forward, up_hint)
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        return np.concatenate([right, up])


# --- render settings ----------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class SceneOptions:
    """Choices that shape the compiled model.  Physics never depends on them."""

    fast_render: bool = True  # no shadows/MSAA, small offscreen buffer (see apply_fast_render)
    decimate_cell: float | None = 0.01  # vertex-cluster size (m) for large visual meshes; None keeps them
    decimate_min_faces: int = 2000  # only meshes with more triangles than this are decimated
    overview: LookAtCamera = OVERVIEW_CAMERA
    wrist: WristCamera = WristCamera()
    offscreen_size: tuple[int, int] = (128, 128)  # grown on demand by d5rl.rendering.make_renderer


def apply_fast_render(spec: mujoco.MjSpec, offscreen_size: tuple[int, int]) -> None:
    """Cheap software rendering: no shadow maps, no multisampling, a buffer sized to the image."""
    spec.visual.quality.shadowsize = 0
    spec.visual.quality.offsamples = 0
    spec.visual.global_.offheight = int(offscreen_size[0])
    spec.visual.global_.offwidth = int(offscreen_size[1])
    for light in spec.lights:
        light.castshadow = False
    for mat in spec.materials:
        mat.reflectance = 0.0


def read_stl(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V,3) float64 and faces (F,3) int32 of a binary STL file (shared corners merged)."""
    raw = Path(path).read_bytes()
    n = int(np.frombuffer(raw, dtype="<u4", count=1, offset=80)[0])
    rec = np.dtype([("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    tri = np.frombuffer(raw, dtype=rec, count=n, offset=84)["v"].reshape(-1, 3).astype(np.float64)
    verts, inverse = np.unique(tri, axis=0, return_inverse=True)
    return verts, inverse.reshape(-1, 3).astype(np.int32)


def decimate(verts: np.ndarray, faces: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertex-clustering simplification: snap vertices to a ``cell``-sized grid, merge each cell's
    vertices into their mean and drop the triangles that collapse.  Deterministic and fast."""
    keys = np.floor(verts / cell).astype(np.int64)
    _, cluster, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    cluster = cluster.reshape(-1)
    new_verts = np.zeros((len(counts), 3))
    np.add.at(new_verts, cluster, verts)
    new_verts /= counts[:, None]
    f = cluster[faces]
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    f = f[keep]
    f = np.unique(np.sort(f, axis=1), axis=0, return_index=True)[1]  # drop duplicate triangles
    f = cluster[faces][keep][np.sort(f)]
    return new_verts, f.astype(np.int32)


def decimate_visual_meshes(spec: mujoco.MjSpec, mesh_root: Path, cell: float, min_faces: int) -> dict[str, int]:
    """Replace every large visual mesh (no collisions) by a decimated copy; returns new face counts."""
    visual = set()
    for geom in spec.geoms:
        if geom.type == mujoco.mjtGeom.mjGEOM_MESH and geom.contype == 0 and geom.conaffinity == 0:
            visual.add(geom.meshname)
    counts = {}
    for mesh in spec.meshes:
        if mesh.name not in visual or not mesh.file.lower().endswith(".stl"):
            continue
        path = mesh_root / mesh.file
        verts, faces = read_stl(path)
        if len(faces) <= min_faces:
            continue
        verts, faces = decimate(verts, faces, cell)
        mesh.file = ""
        mesh.uservert = verts.astype(np.float32).ravel()
        mesh.userface = faces.ravel()
        counts[mesh.name] = len(faces)
    return counts


def _mesh_root(spec: mujoco.MjSpec, xml_path: Path) -> Path:
    return (xml_path.parent / spec.compiler.meshdir).resolve()


def add_cameras(spec: mujoco.MjSpec, overview: LookAtCamera, wrist: WristCamera) -> None:
    pos, xyaxes = overview.pose()
    cam = spec.worldbody.add_camera(name="overview", pos=pos, fovy=overview.fovy)
    cam.alt.type = mujoco.mjtOrientation.mjORIENTATION_XYAXES
    cam.alt.xyaxes = xyaxes
    hand = spec.body(HAND_BODY)
    cam = hand.add_camera(name="wrist", pos=np.asarray(wrist.pos, dtype=float), fovy=wrist.fovy)
    cam.alt.type = mujoco.mjtOrientation.mjORIENTATION_XYAXES
    cam.alt.xyaxes = wrist.xyaxes()


def add_gravity_compensation(spec: mujoco.MjSpec) -> None:
    """Compensate gravity on the arm (as the real Panda's controller does).

    The actions are joint velocities integrated from the *current* joint positions, so without
    compensation a zero action lets the arm sag a little every step (0.6 rad in 4 s at the elbow).
    """
    for body in spec.bodies:
        if body.name.startswith("panda0_"):
            body.gravcomp = 1.0


def build_spec(options: SceneOptions = SceneOptions()) -> mujoco.MjSpec:
    """An editable spec of the kitchen with our cameras and render settings (not compiled)."""
    xml = asset_dir() / "kitchen_assets" / "kitchen_env_model.xml"
    spec = mujoco.MjSpec.from_file(str(xml))
    add_gravity_compensation(spec)
    add_cameras(spec, options.overview, options.wrist)
    if options.fast_render:
        apply_fast_render(spec, options.offscreen_size)
    if options.decimate_cell is not None:
        decimate_visual_meshes(spec, _mesh_root(spec, xml), options.decimate_cell, options.decimate_min_faces)
    return spec


@functools.lru_cache(maxsize=4)
def _compiled(options: SceneOptions) -> mujoco.MjModel:
    return build_spec(options).compile()


def build_model(options: SceneOptions = SceneOptions()) -> mujoco.MjModel:
    """A fresh compiled model (copied from a per-process cache: compiling takes ~1 s)."""
    return _compiled(options).__copy__()


def stock_model() -> mujoco.MjModel:
    """The scene exactly as the asset package ships it (for render benchmarks), plus our cameras."""
    return build_model(SceneOptions(fast_render=False, decimate_cell=None))
