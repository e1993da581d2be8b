"""Floors of the v1 A1 tasks, with the geometry of the D5RL release (``legged_mujoco/arenas``,
``tasks/run.py``).

- ``flat``: the ground plane.
- ``bumpy`` (the direction-conditioned data task): a 20 m × 20 m heightfield centred on the origin
  whose surface lies 0.18-0.24 m above the plane: random heights U(0.75, 1) on a 0.2 m grid,
  interpolated to the 335 × 335 field and scaled by half its 0.5 m elevation.  Beyond ±10 m is the
  plane, a step of ~0.2 m down.
- ``course`` (hiking): the same field shaped as a ring (``0.5 - cos(2πr) / 2`` of the normalised
  radius r, clipped to [0.1, 1]) times the random heights, so the walk from x = -20 crosses a
  ~0.4-0.5 m high rim at x ≈ -5 and again at x ≈ +5; then two ridges, each of two wedges (the
  release's ramp mesh: 5 m long, 15 m wide, rising 1.5 m, set 0.2 m up): up from x = 8.25 to a
  1.2 m crest at x = 12.25 and down to the plane at 16.25, and again 22.25 / 26.25 / 30.25.

Heights are redrawn every episode from the env's seeded generator (:func:`regenerate`).  The
release upsamples the random grid with a cubic spline (``scipy.ndimage.zoom``); here it is
bilinear (numpy only), which the heightfield's own triangles at 6 cm spacing barely tell apart.
"""

from __future__ import annotations

import mujoco
import numpy as np

FLOORS = ("flat", "bumpy", "course")
FIELD_HALF = 10.0  # m, half the side of the square heightfield
FIELD_RES = 335  # rows = columns (the release: int(201 / 6 * 10))
FIELD_ELEVATION = 0.5  # m at data value 1
FIELD_BASE = 0.1  # m, depth of the field's solid base
FIELD_Z = -0.01  # m, the field's offset below the plane
BUMP_SPACING = 0.2  # m between the random heights
BUMP_LOW = 0.75  # random heights are U(BUMP_LOW, 1)
BUMPY_SCALE = 0.5  # the bumpy floor's data = BUMPY_SCALE * heights
# each wedge: (x where it is lowest, x of its crest); bottom at z = -0.3, crest at 1.2, y in [-7.25, 7.75]
WEDGES = ((7.25, 12.25), (17.25, 12.25), (21.25, 26.25), (31.25, 26.25))
WEDGE_Z = (-0.3, 1.2)
WEDGE_Y = (-7.25, 7.75)
WAYPOINTS = ((-10.0, 0.0), (0.0, 0.0), (20.0, 0.0), (40.0, 0.0))  # hiking, in order
HIKING_START = (-20.0, 0.0)
FIELD = "terrain"  # name of the heightfield and of its geom


def add_floor(spec: mujoco.MjSpec, floor: str) -> None:
    """Add ``floor``'s heightfield (heights all zero until :func:`regenerate`), wedges and waypoint markers."""
    if floor not in FLOORS:
        raise ValueError(f"floor must be one of {FLOORS}, got {floor!r}")
    if floor == "flat":
        return
    spec.add_hfield(
        name=FIELD,
        size=[FIELD_HALF, FIELD_HALF, FIELD_ELEVATION, FIELD_BASE],
        nrow=FIELD_RES,
        ncol=FIELD_RES,
        userdata=[0.0] * (FIELD_RES * FIELD_RES),
    )
    spec.worldbody.add_geom(
        name=FIELD, type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname=FIELD, material="groundplane", pos=[0.0, 0.0, FIELD_Z]
    )
    if floor != "course":
        return
    for i, (x_low, x_crest) in enumerate(WEDGES):
        verts = [[x_low, y, WEDGE_Z[0]] for y in WEDGE_Y] + [[x_crest, y, z] for y in WEDGE_Y for z in WEDGE_Z]
        spec.add_mesh(name=f"wedge{i}", uservert=np.ravel(verts).tolist())
        spec.worldbody.add_geom(
            name=f"wedge{i}", type=mujoco.mjtGeom.mjGEOM_MESH, meshname=f"wedge{i}", rgba=[0.0, 0.5, 1.0, 1.0]
        )
    for i, (x, y) in enumerate(WAYPOINTS):
        spec.worldbody.add_site(name=f"waypoint{i}", pos=[x, y, 0.3], size=[0.1, 0, 0], rgba=[0.1, 1.0, 0.1, 0.8])


def random_heights(rng: np.random.Generator) -> np.ndarray:
    """(FIELD_RES, FIELD_RES) heights in [BUMP_LOW, 1]: uniform on a BUMP_SPACING grid, bilinear in between."""
    n = int(2 * FIELD_HALF / BUMP_SPACING)
    grid = rng.uniform(BUMP_LOW, 1.0, (n, n))
    at = np.linspace(0.0, n - 1.0, FIELD_RES)  # the field's rows/columns in grid coordinates
    i = np.minimum(at.astype(int), n - 2)
    f = at - i
    rows = grid[i] * (1 - f)[:, None] + grid[i + 1] * f[:, None]
    return rows[:, i] * (1 - f)[None, :] + rows[:, i + 1] * f[None, :]


def ring() -> np.ndarray:
    """The hiking field's ring-shaped rim: 0.1 within radius 0.1 (of the half side), 1 at 0.5, 0 at 1 and beyond."""
    u = np.linspace(-1.0, 1.0, FIELD_RES)
    r = np.clip(np.hypot(u[:, None], u[None, :]), 0.1, 1.0)
    return 0.5 - np.cos(2 * np.pi * r) / 2


def field_data(floor: str, rng: np.random.Generator) -> np.ndarray:
    """A new heightfield (values in [0, 1], times FIELD_ELEVATION metres) for ``floor``, row-major."""
    heights = random_heights(rng)
    data = ring() * heights if floor == "course" else BUMPY_SCALE * heights
    return data.ravel()


def regenerate(model: mujoco.MjModel, floor: str, rng: np.random.Generator) -> None:
    """Write a new random field into ``model`` (a ``flat`` floor has none)."""
    if floor == "flat":
        return
    h = model.hfield(FIELD)
    start = int(h.adr[0])
    model.hfield_data[start : start + FIELD_RES * FIELD_RES] = field_data(floor, rng)


def field_height(model: mujoco.MjModel, x: float, y: float) -> float:
    """Surface height of the heightfield under (x, y) at its nearest vertex (m; for tests and markers)."""
    h = model.hfield(FIELD)
    res = FIELD_RES
    col = int(round((x + FIELD_HALF) / (2 * FIELD_HALF) * (res - 1)))
    row = int(round((y + FIELD_HALF) / (2 * FIELD_HALF) * (res - 1)))
    if not (0 <= col < res and 0 <= row < res):
        return 0.0
    geom_z = float(model.geom(FIELD).pos[2])
    return geom_z + FIELD_ELEVATION * float(model.hfield_data[int(h.adr[0]) + row * res + col])
