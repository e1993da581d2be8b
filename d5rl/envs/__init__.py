"""Environment families.  Each sub-package registers its tasks in ``registration.py``.

Importing this package chooses the GL backend (:mod:`d5rl.gl`) before any family imports MuJoCo.
"""

from d5rl import gl  # noqa: F401  (sets MUJOCO_GL before any family imports MuJoCo)
