"""Reference fingerprints: committed for every dataset, checked by `d5rl verify --reference`, and
reproduced by a prefix regenerated under a restricted instruction set."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from d5rl import numerics
from d5rl.cli import main
from d5rl.datasets import format as fmt
from d5rl.datasets import references
from d5rl.datasets.generation import dataset_root, dataset_spec
from d5rl.files import dump_json

REPO = Path(__file__).resolve().parents[2]
REFS = references.load_references()


def test_every_registered_dataset_has_a_current_reference():
    for name, task in references.dataset_tasks().items():
        dspec = dataset_spec(task)
        regenerate = f"run `python -m d5rl.datasets.references {name}`"
        assert name in REFS, f"no reference for {name}: {regenerate}"
        ref = REFS[name]
        from d5rl.registry import resolve

        assert (ref["dataset_version"], ref["generator_version"]) == (
            dspec.version,
            str(resolve(dspec.generator).version),
        ), f"stale reference for {name}: {regenerate}"
        assert ref["numerics"] == dspec.numerics, f"{name} is {dspec.numerics} now: {regenerate}"
        whole = dspec.num_episodes if name in references.WHOLE else dspec.episodes_per_shard
        assert ref["num_episodes"] == whole and len(ref["shards"]) == -(-whole // dspec.episodes_per_shard)
        assert all(len(d) == whole for d in ref["episodes"].values())


def flip(root: Path, key: str, episode: int) -> None:
    """Change one value of ``key`` in ``episode`` and re-record the checksums, as a copy made by other
    numerics would be: intact, but other bytes."""
    manifest = fmt.read_manifest(root / fmt.MANIFEST)
    entry = next(s for s in manifest["shards"] if s["episodes"][0] <= episode < s["episodes"][1])
    shard_dir = root / "shards" / entry["name"]
    record = fmt.read_shard_record(shard_dir)
    info = record["arrays"][key]
    rows = references._episode_slices(record["episode_lengths"], info["align"])[episode - entry["episodes"][0]]
    arr = np.load(shard_dir / info["file"])
    arr[rows[0] + 1] = np.nextafter(arr[rows[0] + 1], np.inf)  # one ulp: what a rounding difference does
    np.save(shard_dir / info["file"], arr)
    info["sha256"] = entry["arrays"][key]["sha256"] = fmt.sha256_file(shard_dir / info["file"])
    dump_json(record, shard_dir / fmt.SHARD_META)
    (shard_dir / fmt.STAMP).unlink(missing_ok=True)
    dump_json(manifest, root / fmt.MANIFEST)


def test_verify_reference_says_identical_then_names_the_first_differing_array_and_episode(capsys):
    assert main(["generate", "toy-reach-v0", "--workers", "1"]) == 0
    assert main(["verify", "toy-reach-v0", "--reference"]) == 0
    out = capsys.readouterr().out
    assert "identical to the reference: the first 200 episodes of toy-reach, 5 arrays" in out
    assert "reference: portable numerics" in out and "this copy: portable numerics" in out

    root = dataset_root(dataset_spec("toy-reach-v0"))
    flip(root, "rewards", 131)
    flip(root, "actions", 57)
    assert main(["verify", "toy-reach-v0"]) == 0  # intact: integrity alone cannot tell
    assert main(["verify", "toy-reach-v0", "--reference"]) == 1
    err = capsys.readouterr().err
    assert "differs from the reference: first in array 'actions', episode 57 (in shard-00001)" in err


def test_reference_of_other_data_or_a_shorter_copy_is_named():
    spec = dataset_spec("toy-reach-v0")
    assert main(["generate", "toy-reach-v0", "--workers", "1", "--episodes", "60"]) == 0
    root = dataset_root(spec)
    partial = references.compare(root, REFS["toy-reach"])
    assert partial.identical and "the first 60 episodes" in partial.message and "covers 200" in partial.message
    other = dict(REFS["toy-reach"], dataset_version=spec.version + 1)
    result = references.compare(root, other)
    assert not result.identical and "describe different data" in result.message
    assert "python -m d5rl.datasets.references toy-reach" in result.message


def test_verify_reference_refuses_a_dataset_without_one(capsys):
    with pytest.raises(Exception, match="no reference fingerprint is recorded for test-noref"):
        from tests.datasets.toy import register_toy

        spec = register_toy("noref", num_episodes=2, per_shard=2)
        main(["generate", spec.id, "--workers", "1"])
        references.compare_task(spec)


def restricted_env(home: Path) -> dict[str, str]:
    """A worker environment that also hides AVX and AVX-512 from glibc: libm takes its SSE2 variants, as on
    an x86-64 CPU without AVX (numpy and OpenBLAS are at their baseline already)."""
    env = {**os.environ, "D5RL_HOME": str(home), "PYTHONPATH": str(REPO)}
    env.update(numerics.portable_env(env))
    env["GLIBC_TUNABLES"] = numerics._with_libm_mask(env["GLIBC_TUNABLES"]).replace(
        "glibc.cpu.hwcaps=", "glibc.cpu.hwcaps=-AVX,-AVX512F,-AVX512DQ,"
    )
    return env


def regenerate(task: str, episodes: int, env: dict[str, str], prefix: tuple[str, ...] = ()) -> Path:
    code = (
        f"from d5rl.datasets.generation import generate; "
        f"print(generate({task!r}, num_episodes={episodes}, workers=1, progress=False))"
    )
    out = subprocess.run([*prefix, sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=REPO)
    assert out.returncode == 0, out.stderr[-2000:]
    return Path(out.stdout.strip().splitlines()[-1])


PORTABLE = sorted(name for name, ref in REFS.items() if ref["numerics"] == "portable")


@pytest.mark.skipif(not numerics.supported(), reason="portable numerics: x86-64 Linux with glibc")
@pytest.mark.parametrize("name", PORTABLE)
def test_portable_datasets_regenerate_their_reference_under_a_restricted_instruction_set(name, tmp_path):
    task = references.dataset_tasks()[name]
    root = regenerate(task, 2, restricted_env(tmp_path))
    assert json.loads((root / fmt.MANIFEST).read_text())["numerics"] == "portable"
    result = references.compare(root, REFS[name])
    assert result.identical, result.message
    assert "the first 2 episodes" in result.message


QEMU = shutil.which("qemu-x86_64")


@pytest.mark.slow
@pytest.mark.skipif(
    not numerics.supported() or QEMU is None, reason="user-mode QEMU (`apt install qemu-user`) emulates the other CPUs"
)
@pytest.mark.parametrize("cpu", ["SandyBridge", "Haswell"])  # AVX without FMA; AVX2 and FMA; both without AVX-512
@pytest.mark.parametrize("name", PORTABLE)
def test_portable_datasets_regenerate_their_reference_on_other_cpus(name, cpu, tmp_path):
    # the toy family whole, every other portable dataset's first episode (~100 s each under QEMU)
    env = {**os.environ, "D5RL_HOME": str(tmp_path), "PYTHONPATH": str(REPO)}
    env.update(numerics.portable_env(env))
    episodes = REFS[name]["num_episodes"] if name in references.TOY else 1  # the toy family whole: seconds
    root = regenerate(references.dataset_tasks()[name], episodes, env, prefix=(QEMU, "-cpu", cpu))
    result = references.compare(root, REFS[name])
    first = "the first episode of" if episodes == 1 else f"the first {episodes} episodes of"
    assert result.identical and first in result.message, result.message


def cpu_has_fma() -> bool:
    line = next(ln for ln in Path("/proc/cpuinfo").read_text().splitlines() if ln.startswith("flags"))
    return "fma" in line.split()


@pytest.mark.skipif(
    not numerics.supported() or not cpu_has_fma(),
    reason="a CPU without FMA computes natively what portable numerics pin",
)
def test_native_numerics_fail_the_restricted_instruction_set_comparison(tmp_path):
    # what the test above would say of a generator left on native numerics: WidowX pick-and-place, still
    # native, differs from its portable bytes from the first episode on (libm's FMA variants inside MuJoCo)
    native_env = {k: v for k, v in os.environ.items() if k not in numerics.portable_env()}
    native = regenerate(
        "wx-sorting-pickplacedata-state-v0",
        1,
        {**native_env, "D5RL_HOME": str(tmp_path / "native"), "PYTHONPATH": str(REPO)},
    )
    portable = regenerate("wx-sorting-pickplacedata-state-v0", 1, restricted_env(tmp_path / "portable"))
    result = references.compare(native, references.make_entry(portable, None, "this machine"))
    assert not result.identical
    assert "differs from the reference: first in array 'states', episode 0" in result.message


def test_a_reference_can_be_made_from_a_copy_already_generated_which_is_verified_first(tmp_path, capsys):
    home = Path(os.environ["D5RL_HOME"])
    assert main(["generate", "toy-reach-v0", "--workers", "1"]) == 0
    root = dataset_root(dataset_spec("toy-reach-v0"))
    actions = root / "shards" / "shard-00001" / "actions.npy"
    damaged = bytearray(actions.read_bytes())
    damaged[-1] ^= 1  # a damaged copy must not become the reference: generate repairs it first
    actions.write_bytes(bytes(damaged))
    out = tmp_path / "references.json"
    assert references.main(["toy-reach", "--home", str(home), "--out", str(out)]) == 0
    assert "repairing 1 damaged or missing part(s) of toy-reach: shard-00001" in capsys.readouterr().err
    made = json.loads(out.read_text())["toy-reach"]
    assert {k: v for k, v in made.items() if k != "machine"} == {
        k: v for k, v in REFS["toy-reach"].items() if k != "machine"
    }
    with pytest.raises(Exception, match="--home .* is not a directory"):
        references.main(["toy-reach", "--home", str(tmp_path / "nowhere"), "--out", str(out)])
