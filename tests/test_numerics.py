"""Portable numerics: the variables are merged and probed, and they change what libm computes."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from d5rl import numerics
from d5rl.datasets import format as fmt
from d5rl.datasets.generation import dataset_root, generate
from d5rl.errors import D5RLError
from tests.datasets.toy import register_toy

REPO = Path(__file__).resolve().parents[1]
PINNED = tuple(numerics.portable_env())
pytestmark = pytest.mark.skipif(not numerics.supported(), reason="portable numerics: x86-64 Linux with glibc")


def native_env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in PINNED}
    env["PYTHONPATH"] = str(REPO)
    return env


def portable_env() -> dict[str, str]:
    return {**native_env(), **numerics.portable_env(native_env())}


def cpu_flags() -> set[str]:
    line = next(ln for ln in Path("/proc/cpuinfo").read_text().splitlines() if ln.startswith("flags"))
    return set(line.partition(":")[2].split())


def run(code: str, env: dict[str, str]) -> str:
    return subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True, cwd=REPO
    ).stdout


def test_libm_mask_is_added_to_the_users_tunables():
    assert numerics._with_libm_mask("") == "glibc.cpu.hwcaps=-AVX2,-FMA,-FMA4"
    assert (
        numerics._with_libm_mask("glibc.malloc.check=3:glibc.cpu.hwcaps=-AVX512F,-FMA")
        == "glibc.malloc.check=3:glibc.cpu.hwcaps=-AVX512F,-FMA,-AVX2,-FMA4"
    )


def test_check_names_what_is_pinned_in_each_process():
    check = "from d5rl.numerics import main; main(['--check'])"
    native = run(check, native_env())
    assert "this process: native" in native and "libm      NATIVE" in native and "marker    NATIVE" in native
    portable = run(check, portable_env())
    assert "this process: portable" in portable and "NATIVE" not in portable, portable
    for line in ("numpy     pinned  SIMD targets on: none", "openblas  pinned  core Nehalem"):
        assert line in portable


@pytest.mark.skipif("fma" not in cpu_flags(), reason="a CPU without FMA runs the non-FMA libm anyway")
def test_the_libm_pin_changes_what_libm_computes():
    # glibc's FMA variants of exp/sin differ from the others in the last bit for some inputs: the pin
    # must select the others (the same on every x86-64 CPU) in a process started with it
    code = "import math; print([math.sin(x / 7.0) + math.exp(x / 900.0) for x in range(-20000, 20000)])"
    assert run(code, native_env()) != run(code, portable_env())


def test_a_worker_that_is_not_pinned_refuses_portable_work(monkeypatch):
    if numerics.is_portable():
        monkeypatch.setattr(numerics, "is_portable", lambda: False)
    with pytest.raises(D5RLError, match="not pinned"):
        numerics.require("portable")
    numerics.require("native")
    with pytest.raises(ValueError, match="numerics must be one of"):
        numerics.require("fast")


def test_a_portable_dataset_is_made_by_pinned_workers_even_with_one_worker():
    native = register_toy("numerics-native", num_episodes=4, per_shard=2)
    portable = register_toy("numerics-portable", num_episodes=4, per_shard=2, numerics="portable")
    for spec, want in ((native, numerics.current()), (portable, "portable")):
        root = generate(spec, workers=1, progress=False)
        manifest = fmt.read_manifest(root / fmt.MANIFEST)
        assert manifest["numerics"] == want
        shards = [fmt.read_shard_record(root / "shards" / s["name"]) for s in manifest["shards"]]
        assert [r["numerics"] for r in shards] == [want] * 2
    # the same bytes: the toy generator draws only from its seeded generator
    a, b = (fmt.read_manifest(dataset_root(s.dataset) / fmt.MANIFEST) for s in (native, portable))
    assert [s["arrays"] for s in a["shards"]] == [s["arrays"] for s in b["shards"]]
