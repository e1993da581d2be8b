"""The Ray backend runs the same tiny grid on a local Ray instance started here."""

import json
import time
from pathlib import Path

import pytest

from d5rl.runner import expand_grid, run_bench, write_report
from d5rl.runner.grid import find_cells
from d5rl.training.rundir import RunDir
from tests.runner import toy

ray = pytest.importorskip("ray", reason="ray is not installed (pip install ray) - the Ray backend is optional")

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def local_ray():
    # workers import the test job from this checkout; drop any instance an earlier test in this
    # process started without these settings (ray.init refuses to run twice)
    if ray.is_initialized():
        ray.shutdown()
    ray.init(
        num_cpus=2, include_dashboard=False, log_to_driver=False, runtime_env={"env_vars": {"PYTHONPATH": str(REPO)}}
    )
    yield
    ray.shutdown()


def test_ray_runs_the_tiny_grid(local_ray, tmp_path):
    sentinel = tmp_path / "failed-once"
    cells = expand_grid(
        list(toy.GOALS),
        ["bc", "iql"],
        [0, 1],
        120,
        40,
        job=toy.JOB,
        tuned=False,
        protocol_overrides={"eval_interval": 40, "eval_episodes": 3},
    )
    flaky = expand_grid(
        list(toy.GOALS)[:1], ["td3bc"], [0], 40, 0, overrides={"fail": f"once:{sentinel}"}, job=toy.JOB, tuned=False
    )
    run_dir = tmp_path / "run"
    t0 = time.time()
    result = run_bench(cells + flaky, run_dir, use_ray=True, progress=False)
    wall = time.time() - t0
    assert not result.failed, result.summary()
    assert len(result.ok) == 9
    assert result.attempts[flaky[0].key] == 2 and len(RunDir(flaky[0].directory(run_dir)).read_failures()) == 1
    pids = set()
    for cell, cdir in find_cells(run_dir):
        done = json.loads((cdir / "done").read_text())
        assert done["key"] == cell.key
        for line in (cdir / "log.txt").read_text().splitlines():
            if line.startswith("=== "):
                pids.add(int(line.split(" pid ")[1].split()[0]))
    assert len(pids) == 10  # 9 cells + 1 retry, each in a fresh worker process (max_calls=1)
    # idempotent on Ray too
    again = run_bench(cells, run_dir, use_ray=True, progress=False)
    assert again.ok == [] and len(again.skipped) == 8
    assert write_report(run_dir, reps=100, plots=False).exists()
    print(f"ray tiny grid: {wall:.1f} s")


def test_missing_ray_gives_a_clear_error(monkeypatch):
    import builtins

    from d5rl.errors import MissingDependencyError
    from d5rl.parallel import import_ray

    real_import = builtins.__import__

    def no_ray(name, *args, **kwargs):
        if name == "ray":
            raise ImportError("No module named 'ray'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    with pytest.raises(MissingDependencyError, match="needs the `ray` package") as e:
        import_ray()
    assert "pip install" in e.value.hint


def test_a_ray_client_address_without_ray_client_gives_a_clear_error(monkeypatch):
    from d5rl.errors import MissingDependencyError
    from d5rl.parallel import connect_ray

    def init(address=None, **kw):  # what ray.init says for ray:// when `ray[client]` is not installed
        raise ValueError("Ray Client requires pip package `ray[client]`. If you installed the minimal Ray ...")

    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", init)
    with pytest.raises(MissingDependencyError, match="connects through Ray Client, which is not installed") as e:
        connect_ray("ray://head:10001")
    assert "ray[client]" in e.value.hint
