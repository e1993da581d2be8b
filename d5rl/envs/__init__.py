"""Environment families.  Each sub-package registers its tasks in ``registration.py``."""
