"""The scripted pick-and-place policy that generates the WidowX datasets.

Like COG's scripted policies it reads privileged simulator state (object poses,
bin positions) and walks through stages for each object it handles::

    approach -> descend -> grasp -> lift -> carry -> release -> (next object | retreat)

Each object goes to the bin it is given (the generator picks the wrong one with
probability ``p_wrong``: a "misclassified" object).  An object marked ``miss`` gets a
botched grasp: the gripper closes :data:`MISS_HEIGHT` above the grasp height, on
nothing, and the script carries on as if it held the object.  Gaussian noise is added
to the movement part of every action, so grasps sometimes slip or miss on their own.
"""

from __future__ import annotations

import math

import numpy as np

from d5rl.envs.widowx import model as wm
from d5rl.envs.widowx import scene as wscene

STAGES = ("approach", "descend", "grasp", "lift", "carry", "release", "retreat", "done")
HOVER_Z = 0.14
GRASP_Z = 0.026  # tip height when closing (finger tips ~1 cm above the table)
CARRY_Z = 0.15
RELEASE_Z = 0.12
MISS_HEIGHT = 0.05  # a botched grasp closes this far above the grasp height
GRASP_STEPS = 4
DESCEND_TIMEOUT = 12  # steps; a blocked descent closes the gripper where it is
RELEASE_STEPS = 3


class ScriptedSorter:
    """Picks ``objects`` in order and drops each into its chosen bin.

    ``targets[i]`` is the bin ("shoe" / "toy") object ``i`` is carried to; ``miss[i]``
    botches its grasp (default: none).
    """

    def __init__(
        self,
        env,
        objects: list[str],
        targets: list[str],
        rng: np.random.Generator,
        noise: float = 0.15,
        miss: list[bool] | None = None,
    ):
        self.env = env
        self.objects = list(objects)
        self.targets = list(targets)
        self.miss = list(miss) if miss is not None else [False] * len(self.objects)
        self.rng = rng
        self.noise = float(noise)
        self.current = 0
        self.stage = 0
        self.counter = 0
        self.grasp_xy = None
        self.grasp_yaw = None

    @property
    def stage_name(self) -> str:
        return STAGES[self.stage]

    def _grasp_point(self, name: str) -> tuple[np.ndarray, float]:
        """Above the object's centre, the fingers closing across its narrowest horizontal extent
        (the minor principal axis of its bounding box seen from above: objects lie in any orientation)."""
        env = self.env
        body = env.index.obj_body[name]
        xmat = env.data.xmat[body].reshape(3, 3)
        corners = env.data.xpos[body] + wscene.bbox_corners(env.index, name) @ xmat.T
        xy = corners[:, :2] - corners[:, :2].mean(0)
        _, vecs = np.linalg.eigh(xy.T @ xy)
        axis = vecs[:, 0]  # eigh sorts eigenvalues ascending: the narrow direction
        return corners[:, :2].mean(0), math.atan2(axis[1], axis[0])

    def _move(self, target_xyz, yaw, grip) -> np.ndarray:
        env = self.env
        pose = env.commanded_pose()
        d = (np.asarray(target_xyz) - pose[:3]) / env.max_delta
        waist = math.atan2(pose[1], pose[0])
        yaw = pose[3] + _yaw_err(pose, yaw)  # the gripper is symmetric: nearest equivalent yaw (mod pi)
        psi = waist + math.pi / 2 - yaw
        if abs(psi) > math.pi - 0.1:  # beyond the wrist's range: take the other equivalent
            yaw += math.copysign(math.pi, psi)
        dyaw = (yaw - pose[3]) / env.max_yaw_delta
        a = np.zeros(5)
        a[:3] = np.clip(d, -1, 1)
        a[3] = np.clip(dyaw, -1, 1)
        a[:4] += self.rng.normal(0.0, self.noise, 4)
        a[4] = grip
        return np.clip(a, -1, 1).astype(np.float32)

    def _arrived(self, target_xyz, tol=0.012) -> bool:
        return bool(np.linalg.norm(self.env.tip_position() - np.asarray(target_xyz)) < tol)

    def act(self) -> np.ndarray:
        if self.current >= len(self.objects):
            self.stage = STAGES.index("done")
            home = self.env.commanded_pose()
            return self._move([0.22, 0.0, 0.18], home[3], -1.0)
        name = self.objects[self.current]
        st = STAGES[self.stage]
        if st == "approach":
            xy, yaw = self._grasp_point(name)
            self.grasp_xy, self.grasp_yaw = xy, yaw
            target = [xy[0], xy[1], HOVER_Z]
            if self._arrived(target, 0.02) and abs(_yaw_err(self.env.measured_pose(), yaw)) < 0.15:
                self.stage += 1
                self.counter = 0
            return self._move(target, yaw, -1.0)
        grasp_z = GRASP_Z + (MISS_HEIGHT if self.miss[self.current] else 0.0)
        if st == "descend":
            target = [self.grasp_xy[0], self.grasp_xy[1], grasp_z]
            self.counter += 1
            if self._arrived(target, 0.012) or self.counter > DESCEND_TIMEOUT:
                self.stage += 1
                self.counter = 0
            return self._move(target, self.grasp_yaw, -1.0)
        if st == "grasp":
            self.counter += 1
            if self.counter >= GRASP_STEPS:
                self.stage += 1
            target = [self.grasp_xy[0], self.grasp_xy[1], grasp_z]
            a = self._move(target, self.grasp_yaw, 1.0)
            a[:4] = 0.0
            return a
        bin_xy = wm.BIN_CENTERS[self.targets[self.current]]
        if st == "lift":
            target = [self.grasp_xy[0], self.grasp_xy[1], CARRY_Z]
            if self.env.tip_position()[2] > CARRY_Z - 0.03:
                self.stage += 1
            return self._move(target, self.grasp_yaw, 1.0)
        if st == "carry":
            target = [bin_xy[0], bin_xy[1], RELEASE_Z]
            if self._arrived(target, 0.025):
                self.stage += 1
                self.counter = 0
            return self._move(target, self.grasp_yaw, 1.0)
        if st == "release":
            self.counter += 1
            if self.counter >= RELEASE_STEPS:
                self.stage += 1
            a = self._move([bin_xy[0], bin_xy[1], RELEASE_Z], self.grasp_yaw, -1.0)
            a[:4] = 0.0
            return a
        if st == "retreat":
            target = [bin_xy[0] - 0.05, bin_xy[1] * 0.5, HOVER_Z + 0.02]
            if self._arrived(target, 0.03):
                self.current += 1
                self.stage = 0
            return self._move(target, self.grasp_yaw, -1.0)
        raise AssertionError(st)


def _yaw_err(pose, yaw) -> float:
    return (yaw - pose[3] + math.pi / 2) % math.pi - math.pi / 2
