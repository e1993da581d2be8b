import os

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture(autouse=True)
def _d5rl_home(tmp_path, monkeypatch):
    """Every test gets its own empty dataset cache: tests never touch the user's."""
    monkeypatch.setenv("D5RL_HOME", str(tmp_path / "d5rl-home"))
