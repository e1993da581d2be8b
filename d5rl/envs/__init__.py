"""Environment families.  Each sub-package registers its tasks in ``registration.py``.

d5rl's environments render offscreen: on Linux, ``MUJOCO_GL`` defaults to ``egl`` here, before
any family imports MuJoCo (which reads it once, at import).  A value you set yourself is kept;
``osmesa`` also works.
"""

import os
import sys

if sys.platform.startswith("linux"):
    os.environ.setdefault("MUJOCO_GL", "egl")
