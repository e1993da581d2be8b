"""A scripted, human-like demonstrator for the seven kitchen subtasks.

Each subtask is a short script of *phases* in task space: a target position and
orientation of the gripper's ``end_effector`` site (possibly recomputed every step from
the object's current state, e.g. along a door's arc), a gripper command and a
condition that ends the phase.  A resolved-rate controller (damped least squares on
the site Jacobian, with a null-space pull to a comfortable posture) turns the task-space
error into joint velocities, which are written as the env's normalized actions.

Human-like variation is drawn per episode and per phase from the caller's generator:
overall speed, grasp/approach offsets, a random via point before each approach, brief
pauses, and smoothed action noise.  Everything is a pure function of the generator.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import numpy as np

from d5rl.envs.kitchen.subtasks import SUBTASK_NAMES
from d5rl.production.kitchen.controller import Controller, rot_z
from d5rl.production.kitchen.scripts import OPEN, SCRIPTS, Context, Phase, fixed_target

# --- the policy -----------------------------------------------------------------------------------
# Between subtasks the arm moves in joint space, straight to an inverse-kinematics solution of the
# next subtask's first target found from the rest posture (so the wrist arrives unwound, with the
# roll that leaves the last joint room): task-space moves over such distances run one joint into its
# velocity limit while the others idle, and carry a wound-round wrist from one subtask to the next, leaving
# handles out of reach (the measured effect: CHANGELOG.md, generator kitchen-standard-demos-5).
# A joint-space transit is used when the next target is more than TRANSIT_DISTANCE away, always
# before the hinge cabinet (after a knob the hinge's pre-grasp stalls with joint 6 at its limit),
# and before the microwave or the kettle when a wrist joint is more than WOUND (rad) from the rest
# posture (after the slide cabinet or the light switch their handles are out of reach).
TRANSIT_DISTANCE = 0.4
TRANSIT_ALWAYS = ("hinge cabinet",)
TRANSIT_IF_WOUND = ("microwave", "kettle")
WOUND = 0.8
TRANSIT_SPEED = 1.15  # multiplies Controller.JOINT_SPEED (most operators then move at the joints' limit)
TRANSIT_JITTER = 0.015  # m, std of the offset of the transit's end from the target (path variation)
# Far targets (the kettle on the randomized kitchen's top-right burner, tall kettles most) can draw the
# solve from the rest posture into a branch with the base and elbow joints at their limits, 10-17 cm
# short, from where the arm cannot reach the handle (tall kettles on that burner: 7 of 10 moved).  A
# solve whose hand misses the target by more than IK_MISS (m) is repeated from the rest posture offset
# by each of IK_SEEDS (fixed, drawn once) and the best kept (cost: m, plus 0.1 per rad of rotation).
IK_MISS = 0.05
IK_SEEDS = np.random.default_rng(0).normal(0.0, 0.4, (11, 7))
# Slips (Demonstrator(slips=p), for docs/experiments/kitchen-learnability; the datasets have none): with
# probability p per step of an approach or a transit the arm is pushed off its course for a few steps (a
# random joint velocity held through the slip) and the controller then brings it back, so the data show
# corrections from states the clean script never visits.
SLIP_STEPS = (2, 6)  # a slip lasts 2 to 5 steps
SLIP_SCALE = 0.15  # std of its normalized joint velocity, per arm joint
SLIP_PHASES = ("pre-grasp", "pre-push", "transit", "retreat")  # not the final, precise reach


@dataclasses.dataclass(frozen=True)
class Style:
    """One operator's habits for an episode (drawn by :meth:`Style.sample`)."""

    speed: float  # multiplies every phase's speed
    noise: float  # std of the smoothed action noise
    pause_prob: float  # chance of a short pause before a phase
    via_prob: float  # chance of a detour via a random point before an approach

    @staticmethod
    def sample(rng: np.random.Generator) -> Style:
        """The standard kitchen's demonstrator: speed and noise vary, no detours and no pauses.

        Detours via a random point (up to 30% of approaches) and pauses made the data a mixture from
        the same states ("towards the target" or "towards a random point"), which a unimodal policy
        averages: BC from state scored 0.01 on such data and 0.13 without them (200 episodes, two
        seeds; kitchen-standard data card).  The randomized kitchen's operators keep both (its
        ``Operator.style``): there they are part of what makes data sub-optimal.
        """
        return Style(
            speed=float(rng.uniform(0.9, 1.25)), noise=float(rng.uniform(0.01, 0.05)), pause_prob=0.0, via_prob=0.0
        )


class Demonstrator:
    """Scripted policy solving ``subtasks`` in order; call :meth:`act` once per env step.

    The env must be reset before the policy is made.  ``rng`` drives every random choice.
    """

    def __init__(
        self,
        env,
        subtasks,
        rng: np.random.Generator,
        style: Style | None = None,
        transit_first: bool = False,
        retries: int = 0,
        slips: float = 0.0,
    ):
        self.env = env
        # tries again (up to ``retries`` times, after the remaining subtasks) at a subtask whose object
        # is not at its goal after its script, as a teleoperator would; the standard kitchen's data is
        # made without retries
        self.retries = int(retries)
        # also consider a joint-space transit before the first subtask (the randomized kitchen's far
        # kettle site is out of the resolved-rate reach from the rest pose); the standard kitchen's
        # data keeps its first moves
        self.transit_first = transit_first
        self.slips = float(slips)  # chance per step of a slip (SLIP_PHASES)
        self.subtasks = list(subtasks)
        self.rng = rng
        self.style = style or Style.sample(rng)
        self.ctx = Context(env, rng)
        self.ctrl = Controller(env)
        self._noise = np.zeros(9)
        self._queue = self._phases()
        self._phase: Phase | None = None
        self._frozen = None
        self._flip = False
        self._steps = 0
        self._pause = 0
        self._slip = 0  # steps left of the current slip
        self._slip_push = np.zeros(7)
        self.slipping = False  # whether the last action was a slip's
        self.current_subtask: str | None = None
        self.finished = False
        self.log: list[tuple] = []  # (subtask, phase, steps, final position error) of finished phases

    def _phases(self) -> Iterator[Phase]:
        queue = [(name, 0) for name in self.subtasks]  # (subtask, retries so far)
        k = 0
        while queue:
            name, tries = queue.pop(0)
            self.current_subtask = name
            yield from self._attempt(name, k > 0 or self.transit_first)
            k += 1
            if tries < self.retries and not self.env.completed()[SUBTASK_NAMES.index(name)]:
                queue.append((name, tries + 1))  # not done: try again after the others, as people do
        self.current_subtask = None

    def _attempt(self, name: str, transit: bool) -> Iterator[Phase]:
        """The phases of one try at subtask ``name``, after a joint-space transit if ``transit`` and needed."""
        first = True
        for ph in SCRIPTS[name](self.ctx):
            if first and transit:
                pos, rot = ph.target(self.ctx)
                far = np.linalg.norm(pos - self.ctx.ee_pos) > TRANSIT_DISTANCE
                wound = name in TRANSIT_IF_WOUND and self._wrist_wound()
                if far or wound or name in TRANSIT_ALWAYS:
                    q = self._transit_joints(pos + self.ctx.jitter(TRANSIT_JITTER), rot, ph)
                    yield Phase(
                        "transit",
                        lambda c: (c.ee_pos, c.ee_rot),
                        grip=ph.grip,
                        joints=q,
                        tol=0.15,
                        max_steps=60,
                        speed=TRANSIT_SPEED,
                        freeze=True,
                    )
            if first and self.rng.random() < self.style.via_prob:
                via = self.ctx.ee_pos + self.rng.uniform([-0.08, -0.1, -0.02], [0.08, 0.02, 0.1])
                yield Phase("via", fixed_target(via, self.ctx.ee_rot), grip=ph.grip, tol=0.04, rot_tol=9, max_steps=8)
            first = False
            yield ph

    def _wrist_wound(self) -> bool:
        q = self.ctx.data.qpos[4:7]
        return float(np.abs(q - self.ctrl.posture[4:7]).max()) > WOUND

    def _transit_joints(self, pos: np.ndarray, rot: np.ndarray, phase: Phase) -> np.ndarray:
        """Arm joints (rad) putting the hand at ``pos``/``rot``, solved from the rest posture; of the
        two hand rolls (``phase.any_roll``) the one that reaches best and leaves the last joint room.
        When that misses by more than IK_MISS, the solve is repeated from IK_SEEDS and the best kept."""
        best, best_cost, best_err = None, np.inf, np.inf
        for seeds in ((self.ctrl.posture,), self.ctrl.posture + IK_SEEDS):
            for seed in seeds:
                for flip in (False, True) if phase.any_roll else (False,):
                    q, err, rot_err = self.ctrl.solve_ik(pos, rot @ rot_z(np.pi) if flip else rot, seed)
                    room = min(q[6] - self.ctrl.lo[6], self.ctrl.hi[6] - q[6] - phase.roll_room)
                    cost = err + 0.1 * rot_err + (1.0 if room < 0.2 else 0.0)
                    if cost < best_cost:
                        best, best_cost, best_err = q, cost, err
            if best_err < IK_MISS:
                break
        return best

    def _next_phase(self) -> None:
        if self._phase is not None:
            pos, rot = self._target()
            self.log.append(
                (
                    self.current_subtask,
                    self._phase.name,
                    self._steps,
                    round(float(np.linalg.norm(pos - self.ctx.ee_pos)), 3),
                )
            )
        try:
            self._phase = next(self._queue)
        except StopIteration:
            self._phase = None
            self.finished = True
            return
        self._steps = 0
        self.ctrl.reset()
        self._frozen = self._phase.target(self.ctx) if self._phase.freeze else None
        self._flip = False
        self._flip = self._phase.any_roll and self.ctrl.best_roll(self._target()[1], self._phase.roll_room)
        self._errs: list[float] = []
        self._retried = False
        if self.rng.random() < self.style.pause_prob:
            self._pause = int(self.rng.integers(1, 5))

    def _phase_over(self) -> bool:
        ph = self._phase
        self.ctx.phase_step = self._steps
        if self._steps >= ph.max_steps:
            return True
        if self._steps < ph.min_steps:
            return False
        if ph.joints is not None:
            return float(np.abs(ph.joints - self.ctx.env.data.qpos[:7]).max()) < ph.tol
        if ph.done is not None:
            return ph.done(self.ctx)
        pos, rot = self._target()
        return self.ctrl.reached(pos, rot, ph.tol, ph.rot_tol)

    def _target(self) -> tuple[np.ndarray, np.ndarray]:
        pos, rot = self._frozen if self._frozen is not None else self._phase.target(self.ctx)
        return pos, (rot @ rot_z(np.pi) if self._flip else rot)

    def act(self) -> np.ndarray:
        if self._phase is None and not self.finished:
            self._next_phase()
        while self._phase is not None and self._phase_over():
            self._next_phase()
        if self._phase is None:  # all done: hold still, gripper open
            hold = np.zeros(9)
            hold[7:] = OPEN
            return hold
        ph = self._phase
        self.slipping = False
        if self._slip == 0 and self.slips > 0 and ph.name in SLIP_PHASES and self.rng.random() < self.slips:
            self._slip = int(self.rng.integers(*SLIP_STEPS))
            self._slip_push = self.rng.normal(0.0, SLIP_SCALE, 7)
            self._steps = max(0, self._steps - self._slip)  # as many steps again to get back on course
        if self._slip > 0:  # off course; the phase's clock stops until the slip is over
            self._slip -= 1
            self.slipping = True
            act = np.zeros(9)
            act[:7], act[7:] = self._slip_push, ph.grip
            return np.clip(act, -1.0, 1.0).astype(np.float32)
        self.ctx.phase_step = self._steps
        pos, rot = self._target()
        # stuck (a wrist joint at its limit)? try once with the hand turned the other way round
        self._errs.append(float(np.linalg.norm(pos - self.ctx.ee_pos)))
        if (
            ph.any_roll
            and ph.name.startswith("pre")
            and not self._retried
            and len(self._errs) > 8
            and self._errs[-1] > 2 * ph.tol
            and self._errs[-7] - self._errs[-1] < 0.005
        ):
            self._flip, self._retried = not self._flip, True
            pos, rot = self._target()
        self._steps += 1
        if self._pause > 0:
            self._pause -= 1
            act = np.zeros(9)
            act[7:] = ph.grip
        elif ph.joints is not None:
            act = self.ctrl.joint_action(ph.joints, ph.grip, ph.speed * self.style.speed)
        else:
            act = self.ctrl.action(pos, rot, ph.grip, ph.speed * self.style.speed, ph.integral, ph.straight)
        self._noise = 0.7 * self._noise + 0.3 * self.rng.normal(0.0, self.style.noise, size=9)
        act[:7] += self._noise[:7]
        return np.clip(act, -1.0, 1.0).astype(np.float32)
