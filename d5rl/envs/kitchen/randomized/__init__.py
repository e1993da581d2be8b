"""Randomized Franka Kitchen (KitchenShift-style domain per reset); see :mod:`.domain` and :mod:`.task`."""
