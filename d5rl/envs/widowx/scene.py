"""Named queries of a compiled WidowX scene: joint and actuator indices, object poses and bounding
boxes, which bin an object lies in."""

from __future__ import annotations

import math

import mujoco
import numpy as np

from d5rl.envs.widowx.model import ARM_JOINTS, FINGER_JOINTS, POOL, ROBOT_JOINTS, TIP_SITE
from d5rl.envs.widowx.tabletop import BIN_CENTERS, BIN_FLOOR, BIN_HEIGHT, BIN_INNER_HALF


class SceneIndex:
    """Addresses into qpos/qvel/ctrl of a compiled scene, by name."""

    def __init__(self, model: mujoco.MjModel):
        self.arm_qpos = np.array([model.joint(j).qposadr[0] for j in ARM_JOINTS])
        self.arm_dof = np.array([model.joint(j).dofadr[0] for j in ARM_JOINTS])
        self.finger_qpos = np.array([model.joint(j).qposadr[0] for j in FINGER_JOINTS])
        self.robot_qpos = np.concatenate([self.arm_qpos, self.finger_qpos])
        self.robot_dof = np.array([model.joint(j).dofadr[0] for j in ROBOT_JOINTS])
        self.arm_act = np.array([model.actuator(j).id for j in ARM_JOINTS])
        self.finger_act = np.array([model.actuator(j).id for j in FINGER_JOINTS])
        self.obj_qpos = {n: int(model.joint(f"{n}_joint").qposadr[0]) for n in POOL}
        self.obj_dof = {n: int(model.joint(f"{n}_joint").dofadr[0]) for n in POOL}
        self.obj_body = {n: int(model.body(n).id) for n in POOL}
        self.tip_site = int(model.site(TIP_SITE).id)
        self.pad_geoms = (int(model.geom("left_pad").id), int(model.geom("right_pad").id))
        self.obj_geoms = {n: set(np.flatnonzero(model.geom_bodyid == model.body(n).id).tolist()) for n in POOL}
        # Body-frame bounding box of each object (low, high), from its geoms' boxes.
        self.obj_local_bbox = {n: _body_bbox(model, self.obj_body[n]) for n in POOL}
        self.obj_local_bottom = {n: float(b[0][2]) for n, b in self.obj_local_bbox.items()}

    def object_pose(self, data: mujoco.MjData, name: str) -> tuple[np.ndarray, np.ndarray]:
        a = self.obj_qpos[name]
        return data.qpos[a : a + 3].copy(), data.qpos[a + 3 : a + 7].copy()

    def object_speed(self, data: mujoco.MjData, name: str) -> float:
        """Linear speed plus 0.1 m x angular speed of an object (m/s)."""
        v = self.obj_dof[name]
        return float(np.linalg.norm(data.qvel[v : v + 3]) + 0.1 * np.linalg.norm(data.qvel[v + 3 : v + 6]))

    def set_object_pose(self, data: mujoco.MjData, name: str, pos, quat) -> None:
        a, v = self.obj_qpos[name], self.obj_dof[name]
        data.qpos[a : a + 3] = pos
        data.qpos[a + 3 : a + 7] = quat
        data.qvel[v : v + 6] = 0.0


def _body_bbox(model: mujoco.MjModel, body: int) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame bounding box of a body's collision geometry (mesh vertices; box corners of primitives)."""
    points = []
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    for g in np.flatnonzero(model.geom_bodyid == body):
        if model.geom_group[g] == 2:  # visual-only mesh: the collision pieces define the extent
            continue
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, model.geom_quat[g])
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
            m = model.geom_dataid[g]
            local = model.mesh_vert[model.mesh_vertadr[m] : model.mesh_vertadr[m] + model.mesh_vertnum[m]]
        else:
            local = model.geom_aabb[g][:3] + signs * model.geom_aabb[g][3:]
        points.append(model.geom_pos[g] + local @ rot.reshape(3, 3).T)
    c = np.concatenate(points)
    return c.min(0), c.max(0)


def object_center(model: mujoco.MjModel, data: mujoco.MjData, name: str) -> np.ndarray:
    """World position of the object's centre of mass."""
    return data.xipos[model.body(name).id].copy()


def in_bin(pos: np.ndarray, bin_name: str) -> bool:
    """Whether a point (an object's centre of mass) lies inside a bin's walls, at most 2 cm above their top.

    The 2 cm allow an object resting on the other one in the same bin; an object still
    held at the scripted release height (centre of mass ~10 cm) does not count.
    """
    cx, cy = BIN_CENTERS[bin_name]
    return bool(
        abs(pos[0] - cx) < BIN_INNER_HALF
        and abs(pos[1] - cy) < BIN_INNER_HALF
        and pos[2] < BIN_FLOOR + BIN_HEIGHT + 0.02
        and pos[2] > -0.01
    )


def yaw_quat(yaw: float) -> np.ndarray:
    return np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


def random_quat(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random orientation (a normalized 4-D Gaussian), as MuJoCo's w-x-y-z quaternion."""
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def bbox_corners(index: SceneIndex, name: str) -> np.ndarray:
    """The 8 corners of an object's local bounding box, (8, 3) in its body frame."""
    lo, hi = index.obj_local_bbox[name]
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def lowest_point(index: SceneIndex, name: str, quat) -> float:
    """The lowest z of the object's bounding box when its body frame is rotated by ``quat``."""
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, np.float64))
    return float((bbox_corners(index, name) @ mat.reshape(3, 3).T)[:, 2].min())
