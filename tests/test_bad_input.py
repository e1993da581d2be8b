"""Each bad input gets one line that says what to do, before any work starts (no traceback, nothing written)."""

import numpy as np
import pytest

from d5rl import get_spec, paths
from d5rl.cli import main
from tests.datasets.toy import register_toy

N = get_spec("a1-walk-v0").dataset.num_episodes  # the A1 locomotion dataset's episodes (627 in v1)


def one_line_error(capsys, argv, *needles):
    assert main(argv) == 2
    err = capsys.readouterr().err
    last = err.replace("\r", "\n").strip().splitlines()[-1]  # after any progress bar
    assert last.startswith("error: ") and err.count("error: ") == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in last, last
    return last


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--seed", "-1"], "dataset seed must be an integer"),
        (["--episodes", "1000000000000"], f"has {N} episodes"),
        (["--episodes", str(N + 1)], f"ask for 1 to {N} episodes"),
        (["--episodes", "0"], f"has {N} episodes"),
        (["--episodes", "-5"], f"has {N} episodes"),
        (["--workers", "0"], "workers must be a positive number"),
        (["--workers", "-2"], "workers must be a positive number"),
    ],
)
def test_generate_arguments(capsys, argv, needle):
    one_line_error(capsys, ["generate", "a1-walk-v0", *argv], needle)
    assert not paths.home().exists()  # refused before anything was created


def test_unwritable_home(capsys, tmp_path, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    monkeypatch.setenv("D5RL_HOME", str(blocker / "d5rl"))  # unwritable even for root
    one_line_error(capsys, ["generate", "a1-walk-v0", "--episodes", "1"], "cannot write to", "D5RL_HOME")


def test_full_disk_is_named(capsys, monkeypatch):
    import shutil

    from d5rl.datasets import format as fmt

    spec = register_toy("diskfull", num_episodes=4, per_shard=2)

    def short_write(*a, **k):  # what numpy raises when the disk fills up mid-array: no errno
        raise OSError("503200 requested and 142832 written")

    monkeypatch.setattr(fmt.np, "save", short_write)
    real = shutil.disk_usage
    monkeypatch.setattr(fmt.shutil, "disk_usage", lambda p: real(p)._replace(free=1000))
    one_line_error(capsys, ["generate", spec.id, "--workers", "1"], "is full", "run the same command again")


def test_a_missing_directory_on_a_nearly_full_disk_is_not_called_full(tmp_path, monkeypatch):
    import errno
    import shutil

    from d5rl.datasets import format as fmt

    real = shutil.disk_usage
    monkeypatch.setattr(fmt.shutil, "disk_usage", lambda p: real(p)._replace(free=0))  # like /proc
    gone = FileNotFoundError(errno.ENOENT, "No such file or directory", str(tmp_path / "nope"))
    assert fmt.disk_full_error(tmp_path / "nope", gone) is None  # the OS said why: not the disk
    assert "is full" in str(fmt.disk_full_error(tmp_path / "x", OSError(errno.ENOSPC, "No space left")))
    assert "is full" in str(fmt.disk_full_error(tmp_path / "x", OSError("1 requested and 0 written")))


def test_full_disk_for_real_on_a_tiny_tmpfs(capsys, tmp_path, monkeypatch):
    import subprocess

    mnt = tmp_path / "tiny"
    mnt.mkdir()
    if (
        subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mnt)], capture_output=True).returncode
        != 0
    ):
        pytest.skip("cannot mount a tmpfs here (needs root in a privileged container)")
    try:
        spec = register_toy("tiny", num_episodes=400, per_shard=200)
        monkeypatch.setenv("D5RL_HOME", str(mnt))
        one_line_error(capsys, ["generate", spec.id, "--workers", "1"], "is full")
    finally:
        subprocess.run(["umount", str(mnt)])


@pytest.mark.parametrize(
    "setting, needle",
    [
        ("dataset_episodes=abc", "dataset_episodes='abc' is invalid"),
        ("dataset_episodes=-5", "dataset_episodes=-5 is invalid"),
        ("dataset_episodes=[1,2]", "dataset_episodes=(1, 2) is invalid"),
        ("eval_episodes=0", "eval_episodes=0 is invalid"),
        ("batch_size=0", "batch_size=0 is invalid"),
        ("actor_lr=-1e-4", "actor_lr=-0.0001 is invalid"),
        ("discount=1.5", "discount=1.5 is invalid"),
        ("offline_ratio=2", "it must be a number >= 0 and <= 1 or none"),
        ("hidden_dims=0,3", "hidden_dims=(0, 3) is invalid"),
    ],
)
def test_train_settings(capsys, tmp_path, setting, needle):
    one_line_error(
        capsys,
        ["train", "iql", "a1-walk-v0", "--offline-steps", "10", "--set", setting, "--run-dir", str(tmp_path / "run")],
        needle,
    )
    assert not (tmp_path / "run").exists() and not paths.home().exists()


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--offline-steps", "-5"], "--offline-steps must be a non-negative integer"),
        (["--online-steps", "-1"], "--online-steps must be a non-negative integer"),
        (["--offline-steps", "0"], "nothing to train"),
        (["--seed", "-3"], "--seed must be a non-negative integer"),
        (["--offline-steps", "10", "--set", f"dataset_episodes={N + 1}"], f"ask for 1 to {N} episodes"),
    ],
)
def test_train_arguments(capsys, tmp_path, argv, needle):
    one_line_error(capsys, ["train", "bc", "a1-walk-v0", *argv, "--run-dir", str(tmp_path / "run")], needle)
    assert not (tmp_path / "run").exists() and not paths.home().exists()


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--seeds", "-1"], "--seeds: '-1' is not a seed"),
        (["--seeds", "3-1"], "'3-1' is not a seed or an ascending range"),
        (["--seeds", "a"], "'a' is not a seed"),
        (["--offline-steps", "-1"], "--offline-steps must be a non-negative integer"),
        (["--offline-steps", "0"], "nothing to train"),
        (["--workers", "-2"], "--workers must be >= 0"),
        (["--max-attempts", "0"], "--max-attempts must be >= 1"),
        (["--cpus-per-cell", "0"], "--cpus-per-cell must be > 0"),
        (["--nice", "-5"], "--nice must be from 0 to 19"),
    ],
)
def test_bench_arguments(capsys, tmp_path, argv, needle):
    one_line_error(
        capsys, ["bench", "--tasks", "a1-walk-v0", "--algos", "bc", "--out", str(tmp_path / "grid"), *argv], needle
    )
    assert not (tmp_path / "grid").exists() and not paths.home().exists()


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--reps", "0"], "--reps must be an integer >= 1, got 0"),
        (["--seed", "-2"], "--seed must be an integer >= 0, got -2"),
    ],
)
def test_report_arguments(capsys, tmp_path, argv, needle):
    one_line_error(capsys, ["report", str(tmp_path), "--out", str(tmp_path / "report"), *argv], needle)
    assert not (tmp_path / "report").exists()


def test_bench_seeds_lists_and_ranges():
    from d5rl.runner.cli import _seeds

    assert _seeds(["0-2", "5"]) == [0, 1, 2, 5] and _seeds(["1,2,", "2"]) == [1, 2] and _seeds(["7-7"]) == [7]


def test_eval_episodes(capsys, tmp_path):
    one_line_error(capsys, ["eval", str(tmp_path), "--episodes", "0"], "--episodes must be at least 1")


def test_eval_on_a_task_with_other_spaces(capsys, tmp_path):
    from d5rl.production.toy.data import toy_dataset
    from d5rl.settings import resolve
    from d5rl.training.loop import train

    run = tmp_path / "run"
    train(
        resolve(
            "bc",
            "toy-reach-v0",
            [
                "hidden_dims=8",
                "batch_size=8",
                "eval_episodes=1",
                "eval_envs=1",
                "progress=false",
                "tensorboard=false",
                "checkpoint_interval=8",
            ],
            offline_steps=8,
        ),
        run,
        dataset=toy_dataset(4),
    )
    one_line_error(
        capsys,
        ["eval", str(run), "--task", "toy-reach-pixels-v0"],
        "trained on toy-reach-v0, whose observation space",
        "`d5rl info TASK`",
    )
    one_line_error(capsys, ["eval", str(run), "--task", "toy-reach-v1"], "'toy-reach-v1'")
    one_line_error(capsys, ["eval", str(run), "--seed", "-1"], "seed must be a non-negative integer, got -1")
    one_line_error(
        capsys,
        ["eval", str(run), "--video", str(tmp_path / "v.txt")],
        ".txt is not one of .mp4",
        f"pass e.g. {tmp_path / 'v.mp4'}",
    )
    (tmp_path / "file").touch()
    one_line_error(capsys, ["eval", str(run), "--video", str(tmp_path / "file" / "v.mp4")], "cannot write a video to")
    assert not list(tmp_path.glob("v.*"))


def test_render_refuses_a_video_it_cannot_write_before_rendering(capsys, tmp_path):
    one_line_error(
        capsys,
        ["render", "toy-reach-v0", "--steps", "3", "--out", str(tmp_path / "x.webm")],
        ".webm is not one of .mp4, .mkv, .mov, .avi, .gif",
    )
    assert main(["render", "toy-reach-v0", "--steps", "3", "--out", str(tmp_path / "new" / "x.gif")]) == 0
    assert (tmp_path / "new" / "x.gif").stat().st_size > 0


def test_calibrate_episodes(capsys):
    one_line_error(capsys, ["calibrate", "a1-walk-v0", "--episodes", "0"], "--episodes must be at least 1")


def test_render_names_the_episodes_there_are(capsys, tmp_path):
    one_line_error(
        capsys,
        ["render", "a1-walk-v0", "--episode", "99999", "--out", str(tmp_path / "x.mp4")],
        "no episode 99999",
        f"numbered 0 to {N - 1}",
    )
    assert not paths.home().exists() and not (tmp_path / "x.mp4").exists()


def test_verify_hint_keeps_the_seed(capsys):
    assert main(["verify", "a1-walk-v0", "--seed", "7"]) == 1
    assert "`d5rl generate a1-walk-v0 --seed 7`" in capsys.readouterr().err


def test_evaluate_refuses_zero_episodes():
    from d5rl.errors import D5RLError
    from d5rl.training.evaluation import evaluate

    with pytest.raises(D5RLError, match="0 episodes"):
        evaluate(None, "toy-reach-v0", 0)


@pytest.mark.parametrize(
    "damage, needle",
    [
        ("short_actions", "actions has 8 rows, observations have 9"),
        ("no_actions", "has no 'actions' array"),
        ("nan", "observations has 1 NaN or infinite values (first in row 2)"),
        ("short_terminals", "terminals has 5 rows"),
        ("string_obs", "observations holds |S3 values, not numbers"),
        ("terminals_2d", "terminals has shape (9, 2), expected 1 dimension(s)"),
        ("all_terminal", "no episode has 2 or more rows"),
        ("huge_values", "observations has values beyond ±1000 (first in row 4: 1e+30)"),
        ("complex_actions", "actions holds complex64 values, not numbers"),
        ("declared_huge", "observations declares shape (30000000, 60) (6,866 MiB) in a file of"),
        ("not_hdf5", "is not an HDF5 file"),
    ],
)
def test_import_kitchen_human_refuses_a_broken_d4rl_file(capsys, tmp_path, damage, needle):
    h5py = pytest.importorskip("h5py")
    n = 9
    obs = np.zeros((n, 60), np.float32)
    actions = np.zeros((n, 9), np.float32)
    terminals = np.zeros(n, bool)
    if damage == "short_actions":
        actions = actions[:-1]
    if damage == "nan":
        obs[2, 5] = np.nan
    if damage == "short_terminals":
        terminals = terminals[:5]
    if damage == "string_obs":
        obs = np.full((n, 60), b"abc")
    if damage == "terminals_2d":
        terminals = np.zeros((n, 2), bool)
    if damage == "all_terminal":
        terminals = np.ones(n, bool)
    if damage == "huge_values":
        obs[4, 3] = 1e30
    if damage == "complex_actions":
        actions = actions.astype(np.complex64)
    path = tmp_path / "kitchen_mixed-v0.hdf5"
    with h5py.File(path, "w") as f:
        if damage == "declared_huge":  # a few kB: chunked, never written, so only the fill value exists
            f.create_dataset("observations", shape=(30_000_000, 60), dtype=np.float32, chunks=(1000, 60))
        else:
            f["observations"] = obs
        if damage != "no_actions":
            f["actions"] = actions
        f["terminals"] = terminals
    if damage == "not_hdf5":
        path.write_text("not an HDF5 file\n")
    one_line_error(capsys, ["import-kitchen-human", str(path)], needle)
    assert not paths.home().exists()  # refused before anything was written


@pytest.mark.parametrize("value, needle", [("bogus", "MUJOCO_GL='bogus' is not one of MuJoCo's backends")])
def test_a_bad_mujoco_gl_does_not_break_list_and_rendering_says_why(tmp_path, value, needle):
    import os
    import subprocess
    import sys

    env = {**os.environ, "MUJOCO_GL": value, "D5RL_HOME": str(tmp_path)}
    listed = subprocess.run(
        [sys.executable, "-m", "d5rl.cli", "list"], env=env, capture_output=True, text=True, timeout=120
    )
    assert listed.returncode == 0 and "a1-walk-v0" in listed.stdout, listed.stderr[-2000:]
    render = subprocess.run(
        [
            sys.executable,
            "-c",
            "import d5rl\nenv = d5rl.make_env('toy-reach-pixels-v0')\n"
            "from d5rl.rendering import make_renderer\n"
            "import mujoco\nmake_renderer(mujoco.MjModel.from_xml_string('<mujoco/>'), 8, 8)",
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert render.returncode != 0 and needle in render.stderr.splitlines()[-1], render.stderr[-2000:]
    # a worker process inherits MUJOCO_GL=disable and the reason with it
    child = "import d5rl.envs, d5rl.gl; print(d5rl.gl.GL_PROBLEM)"
    worker = subprocess.run(
        [
            sys.executable,
            "-c",
            "import subprocess, sys\nimport d5rl.envs\n"
            f"print(subprocess.run([sys.executable, '-c', {child!r}], capture_output=True, "
            "text=True).stdout)",
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert needle in worker.stdout, worker.stderr[-2000:]


def test_a_gl_backend_whose_library_is_missing_is_named():
    from d5rl.gl import gl_problem

    assert gl_problem("egl", loadable=lambda *a: True) is None
    assert gl_problem("osmesa", loadable=lambda *a: False) == "MUJOCO_GL=osmesa needs libOSMesa, which is not installed"
    assert gl_problem("disable") is None
