"""The seven kitchen subtasks as data: which object joints, their goal values, the success test.

A subtask is done when the Euclidean distance between its object's joint positions and
the goal is below ``threshold`` (0.3, as in D4RL's and gymnasium-robotics' kitchen).
Goal values are the relay-policy-learning ones.  The randomized kitchen reuses these
definitions unchanged (the joints keep their names in every scene variation).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # only the type: task registration imports these names without loading MuJoCo
    import mujoco

THRESHOLD = 0.3


@dataclasses.dataclass(frozen=True)
class Subtask:
    name: str
    joints: tuple[str, ...]  # object joints compared with the goal (a free joint counts 7 values)
    goal: tuple[float, ...]
    description: str
    threshold: float = THRESHOLD

    def qpos_indices(self, model: mujoco.MjModel) -> np.ndarray:
        import mujoco

        idx = []
        for name in self.joints:
            j = model.joint(name)
            size = {mujoco.mjtJoint.mjJNT_FREE: 7, mujoco.mjtJoint.mjJNT_BALL: 4}.get(
                mujoco.mjtJoint(int(j.type[0])), 1
            )
            adr = int(j.qposadr[0])
            idx.extend(range(adr, adr + size))
        if len(idx) != len(self.goal):
            raise ValueError(f"subtask {self.name}: {len(idx)} joint values but a goal of {len(self.goal)}")
        return np.asarray(idx, dtype=np.int64)

    def distance(self, model: mujoco.MjModel, qpos: np.ndarray) -> float:
        q = np.asarray(qpos)[..., self.qpos_indices(model)]
        return np.linalg.norm(q - np.asarray(self.goal), axis=-1)

    def is_done(self, model: mujoco.MjModel, qpos: np.ndarray):
        return self.distance(model, qpos) < self.threshold


SUBTASKS: dict[str, Subtask] = {
    s.name: s
    for s in (
        Subtask("microwave", ("microwave",), (-0.75,), "open the microwave door"),
        Subtask(
            "kettle",
            ("kettle",),
            (-0.23, 0.75, 1.62, 0.99, 0.0, 0.0, -0.06),
            "move the kettle from the bottom-left to the top-left burner",
        ),
        Subtask("bottom burner", ("knob_Joint_2", "bottom_left_burner"), (-0.88, -0.01), "turn the bottom-left knob"),
        Subtask("top burner", ("knob_Joint_4", "top_left_burner"), (-0.92, -0.01), "turn the top-left knob"),
        Subtask("light switch", ("light_switch", "light_joint"), (-0.69, -0.05), "flip the light switch"),
        Subtask("slide cabinet", ("slide_cabinet",), (0.37,), "slide the right wall-cabinet door open"),
        Subtask("hinge cabinet", ("left_hinge_cabinet", "right_hinge_cabinet"), (0.0, 1.45), "open the hinged door"),
    )
}
SUBTASK_NAMES: tuple[str, ...] = tuple(SUBTASKS)  # fixed column order of `completed` arrays

MIXED = ("microwave", "kettle", "light switch", "slide cabinet")
PARTIAL = ("microwave", "kettle", "bottom burner", "light switch")


class CompletionChecker:
    """Evaluates all seven subtasks on a model (indices resolved once)."""

    def __init__(self, model: mujoco.MjModel, names: tuple[str, ...] = SUBTASK_NAMES):
        self.names = tuple(names)
        self._idx = [SUBTASKS[n].qpos_indices(model) for n in self.names]
        self._goal = [np.asarray(SUBTASKS[n].goal) for n in self.names]
        self._thr = [SUBTASKS[n].threshold for n in self.names]

    def distances(self, qpos: np.ndarray) -> np.ndarray:
        qpos = np.asarray(qpos)
        return np.stack([np.linalg.norm(qpos[..., i] - g, axis=-1) for i, g in zip(self._idx, self._goal)], axis=-1)

    def completed(self, qpos: np.ndarray) -> np.ndarray:
        """Bool array (..., len(names)): is each subtask's object in its goal configuration."""
        return self.distances(qpos) < np.asarray(self._thr)
