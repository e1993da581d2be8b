"""The grid runner end to end with a small numpy job: run, skip, resume after a kill, failures, report."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from d5rl.runner import expand_grid, run_bench, write_report
from d5rl.runner.execute import _cell_lock
from d5rl.runner.grid import GridError, find_cells
from d5rl.training.rundir import RunDir
from tests.runner import toy

REPO = Path(__file__).resolve().parents[2]
TASKS = list(toy.GOALS)
ALGOS = ["bc", "iql"]
SEEDS = [0, 1]
PROTOCOL = {"eval_interval": 40, "eval_episodes": 3}


def grid(offline=120, online=40, **overrides):
    return expand_grid(
        TASKS, ALGOS, SEEDS, offline, online, overrides=overrides, job=toy.JOB, tuned=False, protocol_overrides=PROTOCOL
    )


def done_stamps(run_dir):
    return {c.key: (d / "done").stat().st_mtime_ns for c, d in find_cells(run_dir) if (d / "done").exists()}


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("bench") / "run"
    t0 = time.time()
    result = run_bench(grid(), run_dir, workers=2, progress=False)
    return run_dir, result, time.time() - t0


def test_tiny_grid_runs_end_to_end(finished_run):
    run_dir, result, wall = finished_run
    assert not result.failed, result.summary()
    assert sorted(result.ok) == sorted(c.key for c in grid())
    assert len(result.ok) == len(TASKS) * len(ALGOS) * len(SEEDS) == 8
    for cell, cdir in find_cells(run_dir):
        done = json.loads((cdir / "done").read_text())
        assert done["key"] == cell.key and done["attempt"] == 1
        assert (cdir / "eval.csv").exists() and (cdir / "config.json").exists()
        assert cell.protocol == PROTOCOL
    launches = json.loads((run_dir / "bench.json").read_text())
    assert len(launches) == 1 and len(launches[0]["cells"]) == 8
    assert wall < 120


def test_second_run_skips_finished_cells(finished_run):
    run_dir, _, _ = finished_run
    before = done_stamps(run_dir)
    result = run_bench(grid(), run_dir, workers=2, progress=False)
    assert result.ok == [] and sorted(result.skipped) == sorted(before)
    assert done_stamps(run_dir) == before


def test_redefining_a_finished_cell_is_refused(finished_run):
    run_dir, _, _ = finished_run
    with pytest.raises(GridError, match="already finished with other settings"):
        run_bench(grid(offline=999), run_dir, workers=1, progress=False)


def test_execution_only_settings_keep_a_finished_cell(finished_run):
    """Checkpoint spacing, RAM for the dataset, evaluation envs / processes and progress bars change how a cell
    runs, not what it computes:
    relaunching with them skips finished cells and keeps their record; any other setting is refused."""
    run_dir, _, _ = finished_run
    before = done_stamps(run_dir)
    cells = grid(checkpoint_interval="7", dataset_in_memory_gb="4", eval_envs="2", eval_processes="true")
    result = run_bench(cells, run_dir, workers=1, progress=False)
    assert result.ok == [] and sorted(result.skipped) == sorted(before) and done_stamps(run_dir) == before
    assert all(json.loads((d / "cell.json").read_text())["overrides"] == {} for _, d in find_cells(run_dir))
    with pytest.raises(GridError, match="already finished with other settings"):
        run_bench(grid(checkpoint_interval="7", expectile="0.8"), run_dir, workers=1, progress=False)


def _read_eval(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_report_numbers_match_the_logs(finished_run, tmp_path):
    run_dir, _, _ = finished_run
    (tmp_path / "report" / "curves").mkdir(parents=True)
    (tmp_path / "report" / "curves" / "toy-gone-v0.png").write_bytes(b"")  # a task taken out of the grid
    report = write_report(run_dir, tmp_path / "report", reps=500)
    assert not (tmp_path / "report" / "curves" / "toy-gone-v0.png").exists()
    # recompute every table entry from the cells' eval.csv files, independently of d5rl.runner.logs
    finals = {"offline": {}, "online": {}}
    for task in TASKS:
        for algo in ALGOS:
            for seed in SEEDS:
                rows = _read_eval(run_dir / task / algo / f"seed{seed}" / "eval.csv")
                for phase in finals:
                    scores = [float(r["score"]) for r in rows if r["phase"] == phase]
                    finals[phase].setdefault((task, algo), []).append(scores[-1])
    for phase, name in (("offline", "table1_offline.csv"), ("online", "table2_online.csv")):
        with open(tmp_path / "report" / name, newline="") as f:
            table = {r["task"]: r for r in csv.DictReader(f)}
        assert set(table) == set(TASKS)
        for (task, algo), scores in finals[phase].items():
            assert float(table[task][f"{algo}_mean"]) == pytest.approx(np.mean(scores), abs=1e-12)
            assert float(table[task][f"{algo}_std"]) == pytest.approx(np.std(scores), abs=1e-12)
            assert int(table[task][f"{algo}_n"]) == len(SEEDS)
        md = (tmp_path / "report" / name.replace(".csv", ".md")).read_text()
        for scores in finals[phase].values():
            assert f"{np.mean(scores):.3f} ± {np.std(scores):.3f}" in md
    # aggregate IQM: pooled over tasks and seeds, by the definition
    with open(tmp_path / "report" / "aggregate.csv", newline="") as f:
        agg = list(csv.DictReader(f))
    for row in agg:
        phase = "offline" if row["table"] == "table1_offline" else "online"
        pooled = sorted(s for (t, a), v in finals[phase].items() if a == row["method"] for s in v)
        k = len(pooled) // 4
        assert float(row["iqm"]) == pytest.approx(np.mean(pooled[k : len(pooled) - k]), abs=1e-12)
        assert float(row["iqm_lo"]) <= float(row["iqm"]) <= float(row["iqm_hi"])
        assert float(row["mean"]) == pytest.approx(np.mean(pooled), abs=1e-12)
    assert {(r["table"], r["method"]) for r in agg} == {
        (t, a) for t in ("table1_offline", "table2_online") for a in ALGOS
    }
    text = report.read_text()
    assert "Table 1: offline" in text and "Table 2: offline-to-online" in text
    for task in TASKS:
        png = tmp_path / "report" / "curves" / f"{task}.png"
        assert png.exists() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"curves/{task}.png" in text
    assert "videos/final.gif" in text
    with open(tmp_path / "report" / "scores.csv", newline="") as f:
        scores = list(csv.DictReader(f))
    assert len(scores) == 8 and all(r["done"] == "1" for r in scores)


def test_failures_are_recorded_and_retried_once(tmp_path):
    sentinel = tmp_path / "failed-once"
    cells = (
        expand_grid(TASKS[:1], ["bc"], [0], 40, 0, overrides={"fail": "always"}, job=toy.JOB, tuned=False)
        + expand_grid(TASKS[:1], ["iql"], [0], 40, 0, overrides={"fail": f"once:{sentinel}"}, job=toy.JOB, tuned=False)
        + expand_grid(TASKS[1:], ["bc"], [0], 40, 0, overrides={"fail": "crash"}, job=toy.JOB, tuned=False)
    )
    run_dir = tmp_path / "run"
    result = run_bench(cells, run_dir, workers=2, progress=False)
    always, once, crash = (c.key for c in cells)
    assert set(result.failed) == {always, crash} and result.ok == [once]
    assert result.attempts == {always: 2, once: 2, crash: 2}

    fails = RunDir(run_dir / always).read_failures()
    assert [f["attempt"] for f in fails] == [1, 2]
    assert all("injected failure" in f["error"] and "Traceback" in f["traceback"] for f in fails)
    assert "reach_job" in fails[0]["traceback"]
    assert "injected failure" in (run_dir / always / "error.txt").read_text()
    assert not (run_dir / always / "done").exists()

    assert len(RunDir(run_dir / once).read_failures()) == 1
    assert json.loads((run_dir / once / "done").read_text())["attempt"] == 2

    crashes = RunDir(run_dir / crash).read_failures()
    assert len(crashes) == 2 and all("killed by signal 9" in f["error"] for f in crashes)

    # a later invocation retries unfinished cells again, numbering attempts on from the record
    result2 = run_bench(cells[:1], run_dir, workers=1, progress=False, max_attempts=1)
    assert result2.failed and [f["attempt"] for f in RunDir(run_dir / always).read_failures()] == [1, 2, 3]


def test_report_lists_unfinished_cells(tmp_path):
    cells = expand_grid(TASKS[:1], ["bc"], [0], 40, 0, job=toy.JOB, tuned=False) + expand_grid(
        TASKS[:1], ["iql"], [0], 40, 0, overrides={"fail": "always"}, job=toy.JOB, tuned=False
    )
    run_bench(cells, tmp_path / "run", workers=0, progress=False, max_attempts=1)
    text = write_report(tmp_path / "run", reps=100, plots=False).read_text()
    assert "## Unfinished cells" in text and f"{TASKS[0]}/iql/seed0 | 1 |" in text


def test_cell_running_elsewhere_is_not_raced(tmp_path):
    cells = expand_grid(TASKS[:1], ["bc"], [0], 40, 0, job=toy.JOB, tuned=False)
    cdir = cells[0].directory(tmp_path)
    cdir.mkdir(parents=True)
    with _cell_lock(cdir) as locked:
        assert locked
        result = run_bench(cells, tmp_path, workers=1, progress=False)
    assert result.busy == [cells[0].key] and not (cdir / "done").exists()


DRIVER = """
import sys
from d5rl.runner import expand_grid, run_bench
from tests.runner import toy
cells = expand_grid(list(toy.GOALS), ["bc", "iql"], [0, 1], 120, 0, overrides={"sleep": 0.5}, job=toy.JOB,
                    tuned=False, protocol_overrides={"eval_interval": 40, "eval_episodes": 3})
run_bench(cells, sys.argv[1], workers=2, progress=False)
"""


def test_killed_sweep_resumes_without_redoing_finished_cells(tmp_path):
    run_dir = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-c", DRIVER, str(run_dir)], cwd=REPO)
    try:
        deadline = time.time() + 90
        while time.time() < deadline and len(done_stamps(run_dir) if run_dir.exists() else {}) < 2:
            time.sleep(0.1)
        assert len(done_stamps(run_dir)) >= 2, "the sweep finished no cell in time"
        proc.send_signal(signal.SIGKILL)  # the sweep dies; its workers follow (parent-death signal)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    # the workers die with the sweep (parent-death signal): none may race the resumed sweep.
    # Dying takes a moment on a loaded machine, so allow a few seconds (an orphan would keep
    # running its cell, which takes longer).
    deadline = time.time() + 3
    while True:
        orphans = []
        for proc_dir in Path("/proc").glob("[0-9]*"):
            try:
                cmdline = (proc_dir / "cmdline").read_bytes().decode(errors="replace")
            except OSError:
                continue
            if "d5rl.parallel" in cmdline and str(run_dir) in cmdline:
                orphans.append(cmdline)
        if not orphans or time.time() > deadline:
            break
        time.sleep(0.2)
    if sys.platform.startswith("linux"):
        assert orphans == []
    time.sleep(0.5)
    first = done_stamps(run_dir)
    assert 2 <= len(first) < 8
    cells = expand_grid(
        TASKS, ALGOS, SEEDS, 120, 0, overrides={"sleep": 0.5}, job=toy.JOB, tuned=False, protocol_overrides=PROTOCOL
    )
    result = run_bench(cells, run_dir, workers=2, progress=False)
    assert not result.failed, result.summary()
    assert sorted(result.skipped) == sorted(first)
    assert sorted(result.ok) == sorted(set(c.key for c in cells) - set(first))
    after = done_stamps(run_dir)
    assert {k: after[k] for k in first} == first  # finished cells untouched
    assert len(after) == 8
    for _cell, cdir in find_cells(run_dir):  # interrupted cells restarted clean: one evaluation per step
        steps = [int(r["step"]) for r in _read_eval(cdir / "eval.csv")]
        assert steps == [40, 80, 120]


def test_cli_bench_and_report(tmp_path):
    run_dir = tmp_path / "run"
    cmd = [
        sys.executable,
        "-m",
        "d5rl.runner",
        "bench",
        "--tasks",
        ",".join(TASKS),
        "--algos",
        "bc",
        "iql",
        "--seeds",
        "0-0",
        "--offline-steps",
        "40",
        "--eval-interval",
        "20",
        "--eval-episodes",
        "2",
        "--job",
        toy.JOB,
        "--workers",
        "2",
        "--out",
        str(run_dir),
        "--no-progress",
        "--no-tuned",
    ]
    out = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "4 finished, 0 already done, 0 failed" in out.stderr
    assert (run_dir / "report" / "table1_offline.md").exists()
    assert not (run_dir / "report" / "table2_online.md").exists()  # no online phase was run
    out = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120)
    assert "0 finished, 4 already done" in out.stderr
    out = subprocess.run(
        [sys.executable, "-m", "d5rl.runner", "report", str(run_dir), "--no-plots", "--reps", "100", "--print"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0 and "| BC | IQL |" in out.stdout
    bad = subprocess.run(
        [sys.executable, "-m", "d5rl.runner", "report", str(tmp_path / "nothing")],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert bad.returncode == 2 and "error:" in bad.stderr and "hint:" in bad.stderr


def test_worker_environment_is_single_threaded(tmp_path):
    cells = expand_grid(TASKS[:1], ["bc"], [0], 10, 0, job="tests.runner.test_bench:env_job", tuned=False)
    result = run_bench(cells, tmp_path, workers=1, progress=False)
    assert result.ok, result.summary()
    env = json.loads((cells[0].directory(tmp_path) / "env.json").read_text())
    assert env["OMP_NUM_THREADS"] == "1" and "xla_cpu_multi_thread_eigen=false" in env["XLA_FLAGS"]
    assert env["pid"] != os.getpid()


def env_job(cell, cell_dir):
    keys = ("OMP_NUM_THREADS", "XLA_FLAGS")
    (Path(cell_dir) / "env.json").write_text(json.dumps({**{k: os.environ.get(k) for k in keys}, "pid": os.getpid()}))


def test_datasets_are_generated_once_before_the_cells(tmp_path):
    from d5rl.datasets.generation import dataset_root
    from d5rl.runner.bench import prepare_datasets
    from d5rl.runner.grid import DEFAULT_JOB
    from tests.datasets.toy import register_toy

    spec = register_toy(name="runnerdata", num_episodes=8, per_shard=4)
    root = dataset_root(spec.dataset)
    custom = expand_grid([spec.id], ["bc"], [0], 10, 0, job=toy.JOB, tuned=False)
    assert prepare_datasets(custom, workers=1, progress=False) == {} and not root.exists()  # custom jobs: untouched
    cells = expand_grid(
        [spec.id, "toy-reach-v0"],
        ["bc", "iql"],
        [0, 1],
        10,
        0,
        job=DEFAULT_JOB,
        tuned=False,
        overrides={"dataset_episodes": 4},
    )
    assert prepare_datasets(cells, workers=1, progress=False) == {}
    assert json.loads((root / "manifest.json").read_text())["num_episodes"] == 4  # only the prefix the cells use
    cells = expand_grid([spec.id], ["bc"], [0], 10, 0, job=DEFAULT_JOB, tuned=False)
    assert prepare_datasets(cells, workers=1, progress=False) == {}
    assert json.loads((root / "manifest.json").read_text())["num_episodes"] == 8


def test_bench_parent_never_starts_a_jax_backend():
    """The bench parent resolves every agent's settings but must not start JAX: on a GPU, a parent that
    did would hold most of the card's memory (XLA preallocates) for the whole grid and its workers would
    fail with CUDA out of memory (seen on an H100 with 6 workers). A backend that cannot start (a TPU,
    here) makes any backend start in the child raise."""
    code = (
        "from d5rl.agents import AGENTS, get_agent\n"
        "from d5rl.runner import expand_grid\n"
        "from d5rl.settings import resolve\n"
        "for name in AGENTS:\n"
        "    get_agent(name)\n"
        "    for task in ('toy-reach-pixels-v0', 'toy-reach-v0'):\n"
        "        resolve(name, task)\n"
        "expand_grid(['toy-reach-pixels-v0', 'a1-walk-v0'], list(AGENTS), [0], 100, 100)\n"
        "import jax\n"
        "try:\n"
        "    jax.devices()\n"
        "except RuntimeError:\n"
        "    print('no backend started')\n"
    )
    env = {**os.environ, "JAX_PLATFORMS": "tpu", "PYTHONPATH": str(REPO)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "no backend started" in out.stdout
