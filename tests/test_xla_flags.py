"""XLA flags set where d5rl trains (``import d5rl.agents``), never on ``import d5rl``: appended, never
overriding the user's, and effective."""

import os
import subprocess
import sys

import pytest

from d5rl import xla_flags
from d5rl.xla_flags import CONV_ON_EIGEN, add_xla_flags, configure_default_flags


def test_flags_are_appended_unless_the_user_set_them(monkeypatch):
    env = {}
    add_xla_flags("--a=1", "b=2", environ=env)
    assert env["XLA_FLAGS"] == "--a=1 b=2"
    monkeypatch.setattr(xla_flags, "jaxlib_version", lambda: (0, 10))
    env = {"XLA_FLAGS": "--xla_cpu_experimental_ynn_fusion_type= --other=3"}
    configure_default_flags(environ=env)
    assert env["XLA_FLAGS"] == "--xla_cpu_experimental_ynn_fusion_type= --other=3"  # the user's choice stands
    env = {"XLA_FLAGS": "--other=3"}
    configure_default_flags(environ=env)
    assert env["XLA_FLAGS"] == "--other=3 " + CONV_ON_EIGEN


@pytest.mark.parametrize("version", [(0, 11), None])
def test_the_experimental_flag_is_only_set_for_measured_jaxlib_versions(monkeypatch, version):
    monkeypatch.setattr(xla_flags, "jaxlib_version", lambda: version)
    env = {}
    configure_default_flags(environ=env)
    assert "XLA_FLAGS" not in env


CHECK = """
import d5rl.agents, jax, jax.numpy as jnp, re
x, k, w = (jax.ShapeDtypeStruct(s, jnp.float32) for s in ((64, 32, 32, 16), (3, 3, 16, 32), (256, 256)))
f = lambda x, k, w: (jax.lax.conv_general_dilated(x, k, (1, 1), "SAME", dimension_numbers=("NHWC", "HWIO", "NHWC")), w @ w)
txt = jax.jit(f).lower(x, k, w).compile().as_text()
bodies = [txt.split("%" + name + " (")[1].split("\\n}")[0] for name in re.findall(r"calls=%([\\w.]+)[^\\n]*__ynn_fusion", txt)]
print(*sorted({op for b in bodies for op in ("convolution", "dot") if " " + op + "(" in b}) or ["none"])
"""


@pytest.mark.skipif(
    xla_flags.jaxlib_version() not in xla_flags.CONV_ON_EIGEN_JAXLIB, reason="flag not set for this jaxlib"
)
def test_convolutions_leave_ynnpack_in_a_fresh_process():
    out = subprocess.run(
        [sys.executable, "-c", CHECK],
        capture_output=True,
        text=True,
        timeout=120,
        env={k: v for k, v in os.environ.items() if k != "XLA_FLAGS"},
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["dot"]  # dot products stay on YNNPACK, convolutions do not


def test_import_d5rl_sets_no_xla_flags_and_registers_gymnasium_ids():
    code = (
        "import os, gymnasium, d5rl; assert 'XLA_FLAGS' not in os.environ, os.environ['XLA_FLAGS']; "
        "env = gymnasium.make('d5rl/a1-walk-v0'); print(env.spec.id, os.environ['MUJOCO_GL'])"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "MUJOCO_GL")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["d5rl/a1-walk-v0", "egl"]
    out = subprocess.run(
        [sys.executable, "-c", "import os, d5rl, d5rl.envs.a1.task; print(os.environ['MUJOCO_GL'])"],
        capture_output=True,
        text=True,
        timeout=120,
        env={**env, "MUJOCO_GL": "osmesa"},
    )
    assert out.stdout.strip() == "osmesa"  # the user's choice stands
