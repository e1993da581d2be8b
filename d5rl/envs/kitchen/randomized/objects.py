"""Kettle and microwave models of the randomized kitchen: each with its own collision geometry,
mass and handle, and the grasp plan the scripted operator uses for it.

Built with MjSpec on the stock kitchen.  Model 0 of each is the stock object.

Kettles (8): a body shape (the stock kettle, a box, a wide cylinder, a tall cylinder, a round body
on a foot), each with a collision primitive and a mass of its own, and a handle bar across the top
at the body's own height, thickness and length.  The operator grasps every handle from the front
with the fingers closing on the bar from above and below (the lower finger carries the kettle), at
the model's handle site, along a stretch and with a lift height that fit the model.  Other grasps
fail the scripted operator: a vertical grip on the robot's side of the body held like a jug (the
hanging kettle turns in the fingers: placed in 6 of 12 tries) and a bar running front to back with
the fingers closing on its sides (friction alone does not hold the kettle: 0 of 8).

Microwaves (4): the stock one and three others, each with a body shell that collides (the arm
can hit it), its own door mass, and its own handle: a long thin vertical bar, a thick bar low on the
door, a stubby bar; the operator grasps each at heights along the bar that fit it.  (No horizontal
bars: grasped with the fingers closing vertically, one opens the door in 1 of 4 tries.)
Handles are the door's visual *and* collision geometry; the site the operator aims at sits on
the handle.  Subtask checks stay those of the standard kitchen.
"""

from __future__ import annotations

import dataclasses

import mujoco

from d5rl.envs.kitchen.grasps import KettleGrasp, MicrowaveGrasp

NUM_MICROWAVES = 4
NUM_KETTLES = 8
_CAPSULE, _BOX, _CYL, _ELLIPSOID = (
    mujoco.mjtGeom.mjGEOM_CAPSULE,
    mujoco.mjtGeom.mjGEOM_BOX,
    mujoco.mjtGeom.mjGEOM_CYLINDER,
    mujoco.mjtGeom.mjGEOM_ELLIPSOID,
)
_X_AXIS = (0.7071068, 0.0, 0.7071068, 0.0)  # capsule/cylinder axis along x
_Y_AXIS = (0.7071068, 0.7071068, 0.0, 0.0)  # along y


@dataclasses.dataclass(frozen=True)
class KettleModel:
    name: str
    body: tuple  # (geom type, half sizes, centre height m)
    mass: float  # kg (the stock kettle: 0.88)
    handle_size: tuple  # (radius, half-length) of the bar across the top, m
    rgba: tuple


# body primitives sit on the burner like the stock kettle's collision box (bottom at z = 0)
_WIDE = (_CYL, (0.105, 0.07, 0.0), 0.07)
_TALL = (_CYL, (0.09, 0.1, 0.0), 0.10)
_ROUND = (_ELLIPSOID, (0.115, 0.115, 0.09), 0.105)  # on a flat foot (an ellipsoid alone rocks over)
_BOXY = (_BOX, (0.1, 0.1, 0.065), 0.065)
KETTLES = (
    KettleModel("stock", None, 0.88, (0.032, 0.1), None),
    KettleModel("boxy", _BOXY, 0.8, (0.024, 0.09), (0.75, 0.75, 0.78, 1)),
    KettleModel("wide, thin bar", _WIDE, 1.0, (0.02, 0.08), (0.55, 0.12, 0.1, 1)),
    KettleModel("wide, thick bar", _WIDE, 1.1, (0.03, 0.1), (0.1, 0.3, 0.55, 1)),
    KettleModel("tall, thin bar", _TALL, 0.95, (0.02, 0.07), (0.15, 0.15, 0.15, 1)),
    KettleModel("tall, thick bar", _TALL, 1.0, (0.028, 0.085), (0.85, 0.85, 0.8, 1)),
    KettleModel("round, thick bar", _ROUND, 1.2, (0.026, 0.095), (0.2, 0.45, 0.3, 1)),
    KettleModel("round, long bar", _ROUND, 1.3, (0.022, 0.12), (0.7, 0.5, 0.15, 1)),
)


@dataclasses.dataclass(frozen=True)
class MicrowaveModel:
    name: str
    shell: tuple | None  # half sizes of the body's outer box (None: the stock body)
    door_mass: float  # kg (stock 0.26)
    handle_pos: tuple  # (along the door from its hinge, height from the door's centre) m
    handle_size: tuple  # (radius, half-length) m
    rgba: tuple  # shell colour
    handle_rgba: tuple = (0.9, 0.9, 0.9, 1)


MICROWAVES = (
    MicrowaveModel("stock", None, 0.26, (0.475, 0.0), (0.02, 0.13), None),
    MicrowaveModel("long bar", (0.23, 0.2, 0.17), 0.35, (0.455, 0.0), (0.018, 0.17), (0.2, 0.2, 0.2, 1)),
    MicrowaveModel(
        "low thick bar", (0.26, 0.18, 0.19), 0.3, (0.445, -0.05), (0.024, 0.09), (0.8, 0.8, 0.8, 1), (0.1, 0.1, 0.1, 1)
    ),
    MicrowaveModel(
        "stubby bar", (0.22, 0.21, 0.15), 0.4, (0.47, 0.0), (0.026, 0.07), (0.6, 0.1, 0.1, 1), (0.8, 0.7, 0.1, 1)
    ),
)


def kettle_grasp(k: int) -> KettleGrasp:
    """The operator's plan for kettle model ``k``."""
    m = KETTLES[k]
    if m.body is None:
        return KettleGrasp()
    half = m.handle_size[1]
    return KettleGrasp(along=round(0.2 * half, 4), lift=(0.06, 0.08) if m.body is _TALL else (0.07, 0.09))


def microwave_grasp(k: int) -> MicrowaveGrasp:
    m = MICROWAVES[k]
    if m.shell is None:
        return MicrowaveGrasp()
    reach = round(0.3 * m.handle_size[1], 4)  # grasp heights along the bar: the stock +-4 cm of +-13 cm
    return MicrowaveGrasp(dz=(m.handle_pos[1] - reach, m.handle_pos[1] + reach))


def _pair(body, kind, size, pos, rgba, quat=(1, 0, 0, 0), mass=None, name=None):
    """A visual geom and a colliding twin (the stock scene's convention: group 1 drawn, group 4 collides)."""
    body.add_geom(
        type=kind,
        size=size,
        pos=pos,
        quat=quat,
        rgba=rgba,
        contype=0,
        conaffinity=0,
        group=1,
        name=None if name is None else name + "_visual",
    )
    col = body.add_geom(
        type=kind,
        size=size,
        pos=pos,
        quat=quat,
        rgba=(0.3, 0.3, 1.0, 0.5),
        contype=1,
        conaffinity=1,
        group=4,
        name=name,
    )
    if mass is not None:
        col.mass = mass
    return col


def add_kettle(spec: mujoco.MjSpec, k: int) -> None:
    """Replace the stock kettle's geometry by model ``k`` (0 keeps the stock kettle)."""
    m = KETTLES[k]
    if m.body is None:
        return
    body = spec.body("kettleroot")
    for g in list(body.geoms):
        spec.delete(g)
    kind, size, zc = m.body
    radius = size[0]
    top = zc + (size[1] if kind == _CYL else size[2])
    _pair(
        body,
        kind,
        size,
        (0, 0, zc),
        m.rgba,
        mass=(0.75 if kind == _ELLIPSOID else 0.8) * m.mass,
        name=f"kettle{k}_body",
    )
    dark = (0.1, 0.1, 0.1, 1)
    if kind == _ELLIPSOID:
        _pair(body, _CYL, (0.08, 0.0075, 0), (0, 0, 0.0075), dark, mass=0.05 * m.mass)  # foot
    _pair(body, _CYL, (0.025, 0.045, 0), (-radius - 0.02, 0, zc), m.rgba, quat=_X_AXIS, mass=0.05 * m.mass)  # spout
    _pair(body, mujoco.mjtGeom.mjGEOM_SPHERE, (0.018, 0, 0), (0, 0, top + 0.01), dark, mass=0.02 * m.mass)  # lid knob
    r, half = m.handle_size
    z = top + 0.12  # the hand (20 cm tall with the fingers closing vertically) must clear the body
    _pair(body, _CAPSULE, (r, half, 0), (0, 0, z), dark, quat=_X_AXIS, mass=0.1 * m.mass, name=f"kettle{k}_handle")
    for sx in (-1, 1):  # posts down to the body's top
        _pair(body, _CAPSULE, (0.016, 0.06, 0), (sx * (half - 0.01), 0, z - 0.06), dark, mass=0.015 * m.mass)
    site = next(s for s in body.sites if s.name == "kettle_site")
    site.pos = (0.0, 0.0, z)


def add_microwave(spec: mujoco.MjSpec, k: int) -> None:
    """Microwave model ``k`` (0 keeps the stock one): a colliding shell, the door's mass and handle."""
    m = MICROWAVES[k]
    if m.shell is None:
        return
    body, door = spec.body("microroot"), spec.body("microdoorroot")
    half = m.shell
    # the shell collides with the arm and the kettle (like the stock body's boxes: contype 0,
    # conaffinity 1); it keeps behind the door's plane so the door still swings open
    body.add_geom(
        type=_BOX,
        size=half,
        pos=(0, 0.02, half[2] - 0.02),
        rgba=m.rgba,
        contype=0,
        conaffinity=0,
        group=1,
        name=f"mw_shell{k}",
    )
    body.add_geom(
        type=_BOX,
        size=(half[0], half[1] - 0.02, half[2]),
        pos=(0, 0.04, half[2] - 0.02),
        rgba=(0.3, 0.3, 1.0, 0.5),
        contype=0,
        conaffinity=1,
        group=4,
        name=f"mw_shell{k}_collision",
    )
    # the door's own mass: a plate of the stock door's size (its collision box) of this mass
    door.explicitinertial = True
    door.mass = m.door_mass
    door.ipos = (0.259, -0.026, 0.0)
    a, b, c = 0.518, 0.048, 0.37  # full extents of the door plate, m
    door.inertia = (
        m.door_mass / 12 * (b * b + c * c),
        m.door_mass / 12 * (a * a + c * c),
        m.door_mass / 12 * (a * a + b * b),
    )
    stock_x = door.sites[0].pos[0]
    x, h = m.handle_pos
    r, half_len = m.handle_size
    for g in list(door.geoms):  # the stock handle (a bar and two stand-offs, visual and collision)
        if g.type == _CAPSULE and abs(g.pos[0] - stock_x) < 1e-6:
            spec.delete(g)
    y_bar, y_post = -0.108, -0.075  # the stock handle's distance from the door (bar, middle of stand-offs)
    ends = [(x, y_post, h + s * half_len) for s in (-1, 1)]
    for group, con, rgba in ((1, 0, m.handle_rgba), (4, 1, (0.3, 0.3, 1.0, 0.5))):
        door.add_geom(
            type=_CAPSULE,
            size=(r, half_len, 0),
            pos=(x, y_bar, h),
            rgba=rgba,
            contype=0,
            conaffinity=con,
            group=group,
            name=f"mw{k}_handle" + ("" if con else "_visual"),
        )
        for e in ends:
            door.add_geom(
                type=_CAPSULE,
                size=(min(r, 0.02), 0.03, 0),
                pos=e,
                quat=_Y_AXIS,
                rgba=rgba,
                contype=0,
                conaffinity=con,
                group=group,
            )
    door.sites[0].pos = (x, y_bar, 0.0)  # the bar's height is in the grasp plan's dz
