"""The randomized Franka Kitchen: a new domain (see :mod:`.domain`) on every reset.

Description
    The standard kitchen's seven subtasks, rewards and success checks, in a scene whose microwave
    model (4) and kettle model (8) -- each with its own collision geometry, mass and handle
    (:mod:`.objects`) --, surface looks (cabinet panels, metal fronts, cabinet handles, counter top,
    walls and floor each get one of 6 photographs at one of 2 scales, the stock texture or none,
    tinted per domain), extra lights (1-3, direction and colour), side-camera poses (look-at/distance
    sigma 0.05, angles sigma 1 deg), the kettle's start (one of two burners, +-3 cm in x, -1..+3 cm
    in y, +-20 deg yaw) and the microwave's pose (-5..+3 cm along the counter, -3..+4 cm across,
    0-10 deg) are drawn from the env's seeded generator at every reset.  ``info["domain"]`` /
    ``env.domain`` hold the parameters; ``env.grasp_plans`` how the scripted operator grasps this
    domain's kettle and microwave.  ``quality="high"`` renders with shadows and reflections (figures
    and videos; the datasets use the default ``"fast"``).

Action space
    As the standard kitchen: ``Box(-1, 1, (9,))`` joint velocities.

Observation space
    Dict: ``pixels/left``, ``pixels/right`` (side cameras), ``pixels/wrist``, uint8 (S, S, 3) with
    S = 128 by default, and ``proprio`` (9 joint positions).  Stack 3 frames with
    :class:`d5rl.envs.wrappers.FrameStack`.

Reward
    As the standard kitchen (number of target subtasks in their goal configuration).

Start state
    Rest pose with +-0.05 rad uniform noise on the 7 arm joints; kettle and microwave placed as above.

Episode end
    Truncated after 500 steps.

Version history
    v0: first release.  Domains recorded by older generators (kitchen-randomized-6 and older: other
    surface groups, procedural textures, visual-only object models) are refused by
    ``Domain.from_json``: regenerate such datasets.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from d5rl.envs.kitchen.randomized.domain import (
    QUALITIES,
    Domain,
    apply_domain,
    compiled_variant,
    grasp_plans,
    kettle_start_offset,
)
from d5rl.envs.kitchen.subtasks import MIXED
from d5rl.envs.kitchen.task import KitchenEnv
from d5rl.errors import D5RLError
from d5rl.rendering import sync_materials

CAMERAS = ("left", "right", "wrist")


class RandomizedKitchenEnv(KitchenEnv):
    """Randomized kitchen (see the module docstring)."""

    def __init__(
        self,
        tasks: Sequence[str] = MIXED,
        obs_mode: str = "pixels",
        image_size: int = 128,
        cameras: Sequence[str] = CAMERAS,
        init_noise: float = 0.05,
        render_mode: str | None = None,
        render_size: tuple[int, int] = (240, 320),
        domain: Domain | None = None,
        quality: str = "fast",
        width: int | None = None,
        height: int | None = None,
    ):
        if quality not in QUALITIES:
            raise D5RLError(
                f"quality must be one of {QUALITIES}, got {quality!r}",
                "use 'fast' (datasets) or 'high' (shadows and reflections, for figures)",
            )
        self.quality = quality
        first = domain or Domain.sample(np.random.default_rng(0))
        model = compiled_variant(*first.key, quality)
        super().__init__(
            tasks=tasks,
            obs_mode=obs_mode,
            image_size=image_size,
            cameras=cameras,
            init_noise=init_noise,
            render_mode=render_mode,
            render_size=render_size,
            model=model,
            width=width,
            height=height,
        )
        self._fixed_domain = domain
        self._variants: dict[tuple, tuple] = {}
        self.domain = first
        self.grasp_plans = grasp_plans(first)
        apply_domain(self.model, first, quality)

    def set_domain(self, domain: Domain) -> None:
        """Switch the scene to ``domain`` (recompiles only when a discrete choice changes).

        An environment that has made a renderer keeps each variant it visited with its renderers
        (at most 32 models of ~40 MB): closing an EGL renderer and opening another one rendered
        wrong images (measured), and reuse saves the GL upload.  One that never rendered (state
        observations, dataset generation) keeps only its current model and compiles on a switch.
        """
        if domain.key != self.domain.key:
            if self._renderers:
                self._variants[self.domain.key] = (self.model, self.data, self._renderers)
            if domain.key in self._variants:
                self.model, self.data, self._renderers = self._variants.pop(domain.key)
            else:
                self.model = compiled_variant(*domain.key, self.quality)
                self.data = mujoco.MjData(self.model)
                self._renderers = {}
        apply_domain(self.model, domain, self.quality)
        for r in self._renderers.values():  # a reused renderer still holds the last domain's textures
            sync_materials(r, self.model)
        self.domain = domain
        self.grasp_plans = grasp_plans(domain)

    def __getstate__(self) -> dict:
        # the variants visited keep renderers too (see set_domain); a copy keeps only the current one's model
        return {**super().__getstate__(), "_variants": {}}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            super(KitchenEnv, self).reset(seed=seed)
        domain = self._fixed_domain or Domain.sample(self.np_random)
        if options and "domain" in options:
            d = options["domain"]
            domain = d if isinstance(d, Domain) else Domain.from_json(d)
        self.set_domain(domain)
        super().reset(seed=None, options=options)
        adr = int(self.model.jnt_qposadr[self.model.joint("kettle").id])  # free joint: x, y, z, quat
        self.data.qpos[adr : adr + 2] += kettle_start_offset(domain)
        turn = np.array([np.cos(domain.kettle_yaw / 2), 0.0, 0.0, np.sin(domain.kettle_yaw / 2)])
        mujoco.mju_mulQuat(self.data.qpos[adr + 3 : adr + 7], turn, self.data.qpos[adr + 3 : adr + 7].copy())
        mujoco.mj_forward(self.model, self.data)
        completed = self.completed()
        self._begin_episode(completed)
        obs, info = self._get_obs(), self._info(completed)
        info["domain"] = domain.to_json()
        return obs, info
