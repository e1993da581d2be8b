import os
import signal

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

# A job started with `&` from a non-interactive shell (CI scripts, nohup) ignores SIGINT, and an ignored
# signal stays ignored in every process it starts, so the Ctrl-C tests' subprocesses would never see
# their SIGINT.  Installing a handler here makes the subprocesses start with the default disposition,
# as under a terminal (handlers, unlike "ignore", are reset by exec).
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(autouse=True)
def _d5rl_home(tmp_path, monkeypatch):
    """Every test gets its own empty dataset cache: tests never touch the user's."""
    monkeypatch.setenv("D5RL_HOME", str(tmp_path / "d5rl-home"))
