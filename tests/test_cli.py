import shutil

from d5rl.cli import main
from d5rl.datasets.generation import dataset_root
from d5rl.registry import get_spec, list_tasks
from tests.datasets.toy import register_toy


def test_generate_verify_and_corruption_report(capsys):
    spec = register_toy("cli", num_episodes=6, per_shard=2)
    assert main(["generate", spec.id, "--episodes", "4", "--workers", "1"]) == 0
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "test-cli-v0" in out and "partial (4 ep)" in out
    assert main(["generate", spec.id, "--workers", "1"]) == 0
    assert main(["verify", spec.id]) == 0
    assert "OK: 3 shards intact" in capsys.readouterr().out

    root = dataset_root(spec.dataset)
    (root / "shards/shard-00002/states.npy").unlink()
    assert main(["verify", spec.id]) == 1
    err = capsys.readouterr().err
    assert "CORRUPT" in err and "shard-00002/states.npy: missing" in err

    shutil.rmtree(root / "shards/shard-00002")
    (root / "manifest.json").unlink()
    assert main(["generate", spec.id, "--workers", "1"]) == 0  # regenerates only the damaged shard
    assert main(["verify", spec.id]) == 0


def test_task_prefixes_glob_and_state_twins():
    from d5rl.runner.cli import resolve_tasks

    assert resolve_tasks(["kitchen-standard"]) == ["kitchen-standard-mixed-v0", "kitchen-standard-partial-v0"]
    assert resolve_tasks(["wx-*-state-v0"]) == ["wx-sorting-pickplacedata-state-v0", "wx-sorting-state-v0"]
    a1 = resolve_tasks(["a1"])  # the family's tasks whose data can be made (v1's once its agents are published)
    assert {"a1-walk-v0", "a1-run-v0", "a1-hiking-v0"} <= set(a1)
    assert a1 == [
        t
        for t in list_tasks()
        if t.startswith("a1-") and get_spec(t).dataset.unavailable is None and not get_spec(t).variant
    ]
    assert len(resolve_tasks(["a1", "kitchen-*-state-v0", "wx-*-state-v0"])) == len(a1) + 8


def test_bad_task_is_one_clear_line_not_a_traceback(capsys):
    assert main(["info", "a1-wallk"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: 'a1-wallk' is not a task id") and "Traceback" not in err
    assert main(["verify", "nope-nope-v0"]) == 2
    assert "unknown task" in capsys.readouterr().err


def test_verify_of_missing_dataset_says_generate(capsys):
    spec = register_toy("cli-missing")
    assert main(["verify", spec.id]) == 1
    assert f"d5rl generate {spec.id}" in capsys.readouterr().err


def test_generate_renders_pixel_tasks_unless_told_not_to(tmp_path, monkeypatch):
    from d5rl.cli import main
    from d5rl.datasets.generation import dataset_root, dataset_spec

    root = dataset_root(dataset_spec("wx-sorting-v0"))
    assert main(["generate", "wx-sorting-v0", "--episodes", "1", "--workers", "1", "--no-render"]) == 0
    assert (root / "manifest.json").exists() and not (root / "renders").exists()
    assert main(["generate", "wx-sorting-v0", "--episodes", "1", "--workers", "1"]) == 0
    assert [p.name for p in (root / "renders").iterdir()] == ["side-128x128"]


def test_list_marks_data_from_older_generator_code_as_stale(capsys, monkeypatch):
    from tests.datasets import toy

    spec = register_toy("cli-stale", num_episodes=2, per_shard=2)
    assert main(["generate", spec.id, "--workers", "1"]) == 0
    monkeypatch.setattr(toy.ToyGenerator, "version", "changed", raising=False)
    capsys.readouterr()
    assert main(["list"]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith(spec.id))
    assert "stale (generate --force)" in line


def test_render_writes_the_whole_episode_by_default(tmp_path, capsys):
    import imageio.v3 as iio

    out = tmp_path / "toy.mp4"
    assert main(["render", "toy-reach-v0", "--out", str(out), "--no-progress"]) == 0
    assert "wrote 26 frames" in capsys.readouterr().out  # the first observation + all 25 steps
    assert len(list(iio.imiter(out))) == 26
    assert main(["render", "toy-reach-v0", "--out", str(out), "--steps", "5", "--no-progress"]) == 0
    assert "wrote 6 frames" in capsys.readouterr().out
    assert not list(tmp_path.glob(".*tmp*"))


def test_render_replays_every_stored_state_of_the_episode(tmp_path, capsys):
    import imageio.v3 as iio

    from tests.browse import toy

    assert main(["generate", toy.ENV_TASK, "--workers", "1"]) == 0
    out = tmp_path / "ep.mp4"
    assert main(["render", toy.ENV_TASK, "--episode", "2", "--out", str(out), "--no-progress"]) == 0
    assert "wrote 9 frames" in capsys.readouterr().out  # episode 2: 8 transitions, 9 states
    assert len(list(iio.imiter(out))) == 9


def test_render_and_browse_bad_input_is_one_line(capsys, tmp_path):
    for argv, says in (
        (["render", "toy-reach-v0", "--size", "big"], "WIDTHxHEIGHT"),
        (["render", "toy-reach-v0", "--steps", "0"], "--steps must be at least 1"),
        (["render", "toy-reach-v0", "--episode", "-1"], "--episode must be >= 0"),
        (["browse", str(tmp_path / "missing-run")], "does not exist"),
    ):
        try:
            code = main(argv)
        except SystemExit as e:  # argparse's own errors
            code = e.code
        assert code == 2
        err = capsys.readouterr().err
        assert says in err and "Traceback" not in err


def test_a_closed_pipe_ends_quietly(monkeypatch, capsys):
    """`d5rl list | head -1`: the reader leaving is not a disk problem to report."""
    import sys

    class Closed:
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self):
            pass

    monkeypatch.setattr(sys, "stdout", Closed())
    assert main(["list"]) == 141
    assert capsys.readouterr().err == ""


def test_info_of_a_subtask_scored_task_does_not_ask_for_reference_returns(capsys):
    # kitchen and WidowX score from info["score"]; they have no return references and need none
    assert main(["info", "wx-sorting-state-v0"]) == 0
    out = capsys.readouterr().out
    assert "fraction" in out and "reference returns" not in out


def test_info_says_which_numerics_a_dataset_has(capsys):
    assert main(["info", "toy-reach-v0"]) == 0  # a task without a simulator time step
    out = capsys.readouterr().out
    assert "horizon:      25 steps\n" in out and "numerics:     portable: the same bytes on every x86-64 CPU" in out
    assert main(["info", "wx-sorting-state-v0"]) == 0
    assert "numerics:     native: the bytes may differ across CPUs" in capsys.readouterr().out
