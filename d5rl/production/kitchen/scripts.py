"""The seven kitchen subtasks as scripts of *phases* in task space: a target position and orientation
of the gripper's ``end_effector`` site (possibly recomputed every step from the object's state, e.g.
along a door's arc), a gripper command and a condition that ends the phase."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator

import numpy as np

from d5rl.envs.kitchen import model as km
from d5rl.envs.kitchen.grasps import KettleGrasp, MicrowaveGrasp
from d5rl.production.kitchen.controller import R_FORWARD, R_FORWARD_FLAT, orientation_error, rot_y, rot_z

OPEN, CLOSE = 1.0, -1.0


# The finger pads span -0.044..+0.050 m along the site's z axis: the site sits at the pads' middle and
# the fingertips reach 5 cm beyond it.
FINGERTIP = 0.05


@dataclasses.dataclass
class Phase:
    """One motion: go to ``target(ctx) -> (pos, rot)`` with the gripper at ``grip``."""

    name: str
    target: Callable[[Context], tuple[np.ndarray, np.ndarray]]
    grip: float = OPEN
    tol: float = 0.015  # position tolerance (m) when no ``done`` is given
    rot_tol: float = 0.12  # orientation tolerance (rad)
    done: Callable[[Context], bool] | None = None
    max_steps: int = 40
    speed: float = 1.0  # multiplies the controller's speed limits
    freeze: bool = False  # evaluate ``target`` once when the phase starts (relative moves)
    min_steps: int = 0  # never end before this many steps (e.g. while a glide is under way)
    any_roll: bool = True  # the hand may be turned half a turn about its axis (symmetric grasps)
    roll_room: float = 0.0  # the last joint must keep this much room (rad, positive) for a later turn
    integral: bool = True  # integral action (off where the hand presses against something and would wind up)
    joints: np.ndarray | None = None  # a joint-space move instead: joint targets (rad) of the 7 arm joints
    # when a joint's velocity saturates, scale all joints down together instead of clipping that one,
    # so the hand keeps its direction (final approaches: clipping bent the path into a 4-6 cm sideways
    # drift that put a finger against the hinged door after the microwave, kettle or bottom burner)
    straight: bool = False


def grasp_plan(ctx: Context, subtask: str, default):
    """The env's grasp plan for ``subtask`` (the randomized kitchen's object models), else ``default``."""
    return getattr(ctx.env, "grasp_plans", {}).get(subtask, default)


class Context:
    """What a script reads: the model/data, object accessors and this episode's variation."""

    def __init__(self, env, rng: np.random.Generator):
        self.env = env
        self.model, self.data = env.model, env.data
        self.rng = rng
        self.phase_step = 0  # steps taken in the current phase (set by the policy)
        self._site = env.model.site(km.END_EFFECTOR_SITE).id

    def site(self, name: str) -> np.ndarray:
        return self.data.site_xpos[self.model.site(name).id].copy()

    def body_pos(self, name: str) -> np.ndarray:
        return self.data.xpos[self.model.body(name).id].copy()

    def body_mat(self, name: str) -> np.ndarray:
        return self.data.xmat[self.model.body(name).id].reshape(3, 3).copy()

    def joint(self, name: str) -> float:
        return float(self.data.qpos[self.model.joint(name).qposadr[0]])

    @property
    def ee_pos(self) -> np.ndarray:
        return self.data.site_xpos[self._site].copy()

    @property
    def ee_rot(self) -> np.ndarray:
        return self.data.site_xmat[self._site].reshape(3, 3).copy()

    def kettle_handle_offset(self) -> np.ndarray:
        """The kettle's handle site in the kettle body's frame (models differ)."""
        return self.model.site_pos[self.model.site("kettle_site").id].copy()

    def jitter(self, scale: float) -> np.ndarray:
        return self.rng.normal(0.0, scale, size=3)


def _approach_dir(rot: np.ndarray) -> np.ndarray:
    return rot[:, 2]


def _never(ctx: Context) -> bool:
    return False


def _hold(name: str, grip: float, steps: int) -> Phase:
    """Stay where the gripper is for ``steps`` steps (e.g. while the fingers close)."""
    return Phase(name, lambda c: (c.ee_pos, c.ee_rot), grip=grip, done=_never, max_steps=steps, freeze=True)


def fixed_target(pos: np.ndarray, rot: np.ndarray):
    pos, rot = np.array(pos, dtype=float), np.array(rot, dtype=float)
    return lambda ctx: (pos, rot)


def _grasp_and_swing(
    ctx: Context,
    hinge_body: str,
    handle_site: str,
    joint: str,
    goal: float,
    rot: np.ndarray,
    lead: float,
    depth: float,
    wrist_follow: float = 0.5,
    dz: tuple[float, float] = (-0.04, 0.04),
    enough: float | None = None,
) -> Iterator[Phase]:
    """Grasp a handle on a hinged door and swing it along its arc to ``goal`` (joint value)."""
    handle = ctx.site(handle_site) + np.array([0, 0, ctx.rng.uniform(*dz)])
    n = _approach_dir(rot)
    yield Phase("pre-grasp", fixed_target(handle - (0.12 + ctx.rng.uniform(0, 0.04)) * n, rot), tol=0.03, rot_tol=0.25)
    yield Phase("reach", fixed_target(handle + depth * n, rot), tol=0.012, max_steps=30, speed=0.8, straight=True)
    yield Phase("grasp", fixed_target(handle + depth * n, rot), grip=CLOSE, done=_never, max_steps=4)
    hinge = ctx.body_pos(hinge_body)
    q0 = ctx.joint(joint)
    grip_offset = (handle + depth * n) - hinge
    sign = np.sign(goal - q0)

    def swing(c: Context):
        q = c.joint(joint)
        qt = q + sign * lead
        qt = min(qt, goal) if sign > 0 else max(qt, goal)
        # the handle is a vertical bar: the fingers can slide around it, so the hand only turns
        # with part of the door's rotation (less arm reconfiguration, as people do)
        return hinge + rot_z(qt - q0) @ grip_offset, rot_z(wrist_follow * (qt - q0)) @ rot

    enough = goal if enough is None else enough
    history: list[float] = []

    def swung(c: Context) -> bool:
        q = c.joint(joint)
        history.append(q)
        if sign * (q - enough) >= 0:
            return True
        # stalled (the arm is at the end of its reach) once far enough for the subtask to count
        stalled = len(history) > 8 and abs(history[-1] - history[-6]) < 0.01
        return stalled and sign * (q - (enough - sign * 0.12)) >= 0

    yield Phase("swing", swing, grip=CLOSE, done=swung, max_steps=50)
    yield _hold("release", OPEN, 3)
    yield Phase(
        "retreat",
        lambda c: (c.ee_pos - 0.12 * c.ee_rot[:, 2], c.ee_rot),
        tol=0.04,
        rot_tol=9,
        max_steps=15,
        freeze=True,
    )


def microwave(ctx: Context) -> Iterator[Phase]:
    plan = grasp_plan(ctx, "microwave", MicrowaveGrasp())
    yaw = np.arctan2(-ctx.body_mat("microdoorroot")[0, 1], ctx.body_mat("microdoorroot")[1, 1])
    rot = rot_z(yaw) @ R_FORWARD
    yield from _grasp_and_swing(
        ctx, "microdoorroot", "microhandle_site", "microwave", -0.72, rot, 0.4, plan.depth, dz=plan.dz, enough=-0.62
    )


def hinge_cabinet(ctx: Context) -> Iterator[Phase]:
    yield from _grasp_and_swing(
        ctx,
        "hingerightdoor",
        "hinge_site2",
        "right_hinge_cabinet",
        1.6,
        R_FORWARD,
        0.35,
        0.015,
        dz=(-0.10, -0.03),
        enough=1.45,
    )


def slide_cabinet(ctx: Context) -> Iterator[Phase]:
    handle = ctx.site("slide_site") + np.array([0, 0, ctx.rng.uniform(-0.05, 0.05)])
    rot = R_FORWARD
    n = _approach_dir(rot)
    yield Phase("pre-grasp", fixed_target(handle - (0.12 + ctx.rng.uniform(0, 0.04)) * n, rot), tol=0.03, rot_tol=0.25)
    yield Phase("reach", fixed_target(handle + 0.015 * n, rot), tol=0.012, max_steps=30, speed=0.8, straight=True)
    yield Phase("grasp", fixed_target(handle + 0.015 * n, rot), grip=CLOSE, done=_never, max_steps=4)
    target = ctx.rng.uniform(0.36, 0.42)

    def pull(c: Context):
        q = c.joint("slide_cabinet")
        return handle + 0.015 * n + np.array([min(q + 0.12, target), 0, 0]), rot

    yield Phase(
        "slide", pull, grip=CLOSE, done=lambda c: c.joint("slide_cabinet") >= target - 0.03, max_steps=50, speed=0.7
    )
    yield _hold("release", OPEN, 3)
    yield Phase("retreat", lambda c: (c.ee_pos - 0.12 * n, rot), tol=0.04, rot_tol=9, max_steps=15, freeze=True)


def _knob(ctx: Context, knob_body: str, joint: str, goal: float) -> Iterator[Phase]:
    # the knob's ridge sticks out 3.6 cm from its plate; the fingertips stop just short of the plate
    plate = ctx.body_pos(knob_body) + np.array([0, -0.021, 0])
    center = plate - np.array([0, FINGERTIP + 0.008, 0])
    rot = R_FORWARD  # fingers across the ridge
    n = _approach_dir(rot)
    # the wrist turns the knob by ~1.2 rad: approach with the hand roll that leaves the last joint room
    yield Phase(
        "pre-grasp",
        fixed_target(center - (0.10 + ctx.rng.uniform(0, 0.04)) * n, rot),
        tol=0.03,
        rot_tol=0.25,
        roll_room=1.3,
    )
    yield Phase("reach", fixed_target(center, rot), tol=0.02, max_steps=20, speed=0.8, roll_room=1.3)
    yield Phase("grasp", fixed_target(center, rot), grip=CLOSE, done=_never, max_steps=4)

    def turn(c: Context):
        angle = -c.joint(joint)  # the knob turns about -y; the gripper turns about +y
        return center, rot_y(min(angle + 0.8, -goal + 0.5)) @ rot  # the grip slips ~0.3 rad

    history: list[float] = []

    def turned(c: Context) -> bool:
        q = c.joint(joint)
        history.append(q)
        stalled = len(history) > 6 and abs(history[-1] - history[-5]) < 0.01
        return q <= goal + 0.15 or (stalled and q <= goal + 0.3)

    flipped = {}

    def turn_same_roll(c: Context):  # keep the roll the hand grasped with
        pos, r = turn(c)
        if "flip" not in flipped:
            flipped["flip"] = np.linalg.norm(orientation_error(r, c.ee_rot)) > np.pi / 2
        return pos, (r @ rot_z(np.pi) if flipped["flip"] else r)

    yield Phase("turn", turn_same_roll, grip=CLOSE, done=turned, max_steps=30, speed=0.8, any_roll=False)
    yield _hold("release", OPEN, 3)
    yield Phase("retreat", lambda c: (c.ee_pos - 0.10 * n, c.ee_rot), tol=0.04, rot_tol=9, max_steps=15, freeze=True)


def bottom_burner(ctx: Context) -> Iterator[Phase]:
    yield from _knob(ctx, "knob 2", "knob_Joint_2", -1.0)


def top_burner(ctx: Context) -> Iterator[Phase]:
    yield from _knob(ctx, "knob 4", "knob_Joint_4", -1.0)


def light_switch(ctx: Context) -> Iterator[Phase]:
    tip = ctx.site("light_site")
    rot = R_FORWARD  # (the half-turned hand would need the 5th joint past its limit to push)
    # push a little below the lever's axis so the fingers do not ride over it
    side = np.array([0.05 + ctx.rng.uniform(0, 0.01), 0.0, ctx.rng.uniform(-0.012, -0.004)])
    yield Phase(
        "pre-push",
        fixed_target(tip + side + np.array([0, -0.10, 0]), rot),
        grip=CLOSE,
        tol=0.03,
        rot_tol=0.25,
        any_roll=False,
    )
    yield Phase(
        "reach",
        fixed_target(tip + side + np.array([0, -0.01, 0]), rot),
        grip=CLOSE,
        tol=0.012,
        rot_tol=0.06,
        max_steps=30,
        speed=0.8,
        any_roll=False,
        integral=False,
        straight=True,
    )
    yield Phase(
        "push",
        fixed_target(tip + np.array([-0.12, -0.01, side[2]]), rot),
        grip=CLOSE,
        done=lambda c: c.joint("light_switch") <= -0.6,
        max_steps=40,
        speed=0.5,
        any_roll=False,
        integral=False,
    )
    yield Phase(
        "retreat",
        lambda c: (c.ee_pos + np.array([0, -0.12, 0]), rot),
        grip=CLOSE,
        tol=0.04,
        rot_tol=9,
        max_steps=15,
        freeze=True,
    )


KETTLE_GOAL_HANDLE = np.array([-0.234, 0.748, 1.879])  # handle site with the kettle at its goal pose
KETTLE_STOCK_HANDLE = np.array([0.0, 0.0, 0.259])  # the stock kettle's handle site in the kettle's frame


def _glide(start: np.ndarray | None, goal: np.ndarray, rot: np.ndarray, steps: int, relative: bool = False):
    """A target that moves from ``start`` (None: where the hand is when the phase starts) to ``goal``
    (``relative``: an offset from the start) over ``steps`` steps with a smooth (cosine) speed
    profile, so carried objects are not jerked."""
    goal = np.asarray(goal, float)
    state = {"start": None if start is None else np.asarray(start, float)}

    def target(ctx: Context):
        if state["start"] is None:
            state["start"] = ctx.ee_pos
        a = state["start"]
        b = a + goal if relative else goal
        u = min(ctx.phase_step / steps, 1.0)
        return a + (b - a) * (0.5 - 0.5 * np.cos(np.pi * u)), rot

    return target


def kettle(ctx: Context) -> Iterator[Phase]:
    """Grasp the handle from the front (palm against it), lift, glide to the top-left burner, set
    it down, let go.  (From above, the knob panel over the top burners is in the way.)"""
    plan = grasp_plan(ctx, "kettle", KettleGrasp())
    rot = R_FORWARD_FLAT
    up = np.array([0.0, 0.0, 1.0])
    handle = ctx.site("kettle_site") + np.array([ctx.rng.uniform(-plan.along, plan.along), 0, 0])
    grasp = handle + np.array([0, ctx.rng.uniform(0.0, 0.01), 0])
    n = _approach_dir(rot)
    offset = grasp - ctx.site("kettle_site")
    goal_handle = KETTLE_GOAL_HANDLE + (ctx.kettle_handle_offset() - KETTLE_STOCK_HANDLE)
    yield Phase("pre-grasp", fixed_target(grasp - ctx.rng.uniform(0.10, 0.14) * n, rot), tol=0.03, rot_tol=0.2)
    # follow the handle live: the arm may have nudged the kettle on its way
    yield Phase(
        "reach", lambda c: (c.site("kettle_site") + offset, rot), tol=0.01, max_steps=25, speed=0.8, straight=True
    )
    yield _hold("grasp", CLOSE, 5)
    lift = ctx.rng.uniform(*plan.lift)
    n_lift = int(ctx.rng.integers(5, 8))
    yield Phase(
        "lift", _glide(None, lift * up, rot, n_lift, relative=True), grip=CLOSE, done=_never, max_steps=n_lift + 2
    )
    goal = goal_handle + np.array([ctx.rng.uniform(-0.01, 0.01), ctx.rng.uniform(-0.005, 0.015), 0.0])
    n_carry = int(ctx.rng.integers(18, 26))
    yield Phase(
        "carry",
        _glide(None, goal + lift * up, rot, n_carry),
        grip=CLOSE,
        tol=0.02,
        rot_tol=0.3,
        min_steps=n_carry,
        max_steps=n_carry + 15,
    )
    yield Phase("lower", _glide(None, goal + 0.005 * up, rot, n_lift), grip=CLOSE, done=_never, max_steps=n_lift + 2)
    yield _hold("release", OPEN, 6)  # the fingers need ~0.4 s to clear the thick handle

    def back_off(c: Context):  # straight back until the fingers are clear of the handle
        p = c.ee_pos
        p[1] = min(p[1], c.site("kettle_site")[1]) - 0.12
        return p, rot

    yield Phase("retreat", back_off, tol=0.03, rot_tol=9, max_steps=15, freeze=True)


SCRIPTS: dict[str, Callable[[Context], Iterator[Phase]]] = {
    "microwave": microwave,
    "kettle": kettle,
    "bottom burner": bottom_burner,
    "top burner": top_burner,
    "light switch": light_switch,
    "slide cabinet": slide_cabinet,
    "hinge cabinet": hinge_cabinet,
}
