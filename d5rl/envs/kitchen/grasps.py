"""Where the kitchen's object models are grasped: the handle geometry each microwave and kettle model
declares (the defaults are the stock objects'). The randomized kitchen's models give one each
(:func:`d5rl.envs.kitchen.randomized.objects.kettle_grasp`, ``RandomizedKitchenEnv.grasp_plans``); the
scripted demonstrator (:mod:`d5rl.production.kitchen.scripts`) reads them."""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class MicrowaveGrasp:
    """How the operator grasps the microwave door's handle, a vertical bar (defaults: the stock one's)."""

    dz: tuple[float, float] = (-0.04, 0.04)  # m, uniform grasp height from the handle site along the bar
    depth: float = 0.015  # m past the handle's axis


@dataclasses.dataclass(frozen=True)
class KettleGrasp:
    """How the operator grasps the kettle's handle (a horizontal bar on top, from the front, the fingers
    closing on it from above and below) and lifts it; the defaults are the stock kettle's."""

    along: float = 0.015  # m, uniform grasp offset along the bar (+-)
    lift: tuple[float, float] = (0.07, 0.09)  # m, uniform lift height
