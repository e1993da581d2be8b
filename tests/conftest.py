import atexit
import os
import shutil
import signal
import tempfile

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

# One JAX compilation cache for the whole test session, in a temporary folder that is removed at the end.
# Tests build the same small agents again and again, many of them in `d5rl` subprocesses (which inherit
# the environment variable), and the `-n 2` workers, which would otherwise each compile every program from
# scratch: the CI suite went from 16:17 to 9:03 on a 2-core Xeon.  Tests only: a user's cache could sit on a
# home folder shared by machines with different CPUs.
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    _jax_cache = tempfile.mkdtemp(prefix="d5rl-test-jax-cache-")
    atexit.register(shutil.rmtree, _jax_cache, ignore_errors=True)
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _jax_cache
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.1")

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
