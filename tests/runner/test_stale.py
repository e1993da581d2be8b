"""Results follow their data: a cell trained on a dataset its task no longer has (an older dataset or
generator version) is stale; the report leaves it out of every table and lists it, and the same bench
command trains it again."""

import csv
import dataclasses
import json
from pathlib import Path

import pytest

from d5rl.datasets.generation import data_identity, stale_data
from d5rl.runner import expand_grid, run_bench, write_report
from d5rl.runner.grid import stale_reason
from d5rl.runner.report import ReportError

JOB = "tests.runner.test_stale:data_job"
TASK = "toy-reach-v0"


def data_job(cell, cell_dir):
    """Records the data it "trained on" the way d5rl's trainer does (config.json), and one evaluation."""
    cell_dir = Path(cell_dir)
    (cell_dir / "config.json").write_text(json.dumps({"dataset": {**data_identity(cell.task), "episodes": 7}}))
    (cell_dir / "eval.csv").write_text(f"step,score\n{cell.offline_steps},{0.25 * (cell.seed + 1)}\n")
    return {"episodes": 4}


def test_a_result_is_stale_when_its_dataset_or_generator_version_changed():
    now = data_identity(TASK)
    assert set(now) == {"dataset", "dataset_version", "generator_version", "seed"}
    assert stale_data(TASK, {**now, "episodes": 3}) is None
    assert stale_data(TASK, None) is None  # nothing recorded: cannot tell
    older = {**now, "dataset_version": now["dataset_version"] - 1}
    why = stale_data(TASK, older)
    assert (
        why is not None
        and f"v{now['dataset_version'] - 1}" in why
        and f"now toy-reach v{now['dataset_version']}" in why
    )
    assert stale_data(TASK, {**now, "generator_version": "toy-reach-0-old"}) is not None
    assert stale_data("no-such-task-v0", older) is None  # a task only a custom job knows


def _make_stale(cell_dir: Path) -> None:
    cfg = json.loads((cell_dir / "config.json").read_text())
    cfg["dataset"]["dataset_version"] -= 1
    (cell_dir / "config.json").write_text(json.dumps(cfg))


def test_stale_cells_leave_the_tables_and_the_same_command_trains_them_again(tmp_path):
    cells = expand_grid([TASK], ["bc"], [0, 1], 10, 0, job=JOB, tuned=False)
    first = run_bench(cells, tmp_path, workers=0, progress=False)
    assert sorted(first.ok) == sorted(c.key for c in cells) and not first.stale
    old, current = cells
    _make_stale(old.directory(tmp_path))
    assert stale_reason(old, old.directory(tmp_path)) is not None
    assert stale_reason(current, current.directory(tmp_path)) is None

    report = write_report(tmp_path, reps=50, plots=False).read_text()
    assert "1 of 2 cells finished (1 more on older data" in report
    assert f"| {old.key} | trained on toy-reach v" in report
    with open(tmp_path / "report" / "table1_offline.csv", newline="") as f:
        [row] = list(csv.DictReader(f))
    assert row["bc_n"] == "1" and float(row["bc_mean"]) == pytest.approx(0.5)  # seed 1's score only
    protocol = (tmp_path / "report" / "protocol.md").read_text()
    assert f"| {TASK} | BC | 1 | 10 | 4 episodes | toy-reach v" in protocol and "7 episodes" in protocol

    again = run_bench(cells, tmp_path, workers=0, progress=False)
    assert again.stale == [old.key] and again.ok == [old.key] and again.skipped == [current.key]
    assert "1 rerun on new data" in again.summary()
    assert stale_reason(old, old.directory(tmp_path)) is None
    report = write_report(tmp_path, reps=50, plots=False).read_text()
    assert "Stale cells" not in report and "2 of 2 cells finished." in report

    third = run_bench(cells, tmp_path, workers=0, progress=False)
    assert sorted(third.skipped) == sorted(c.key for c in cells) and not third.ok


def test_a_result_is_stale_when_its_agent_version_or_resolved_settings_changed(tmp_path):
    """d5rl's trainer records the agent's version and resolved settings in config.json: a cell trained by an
    older version of the agent's code, or with a setting that now resolves otherwise, is stale."""
    from d5rl.agents import get_agent
    from d5rl.runner.grid import stale_agent
    from d5rl.settings import resolve

    [cell] = expand_grid([TASK], ["bc"], [0], 10, 0)
    r = resolve("bc", TASK, offline_steps=10)
    record = {**r.to_json(), "seed": 0, "agent_version": get_agent("bc")[0].version}

    def why(rec):
        (tmp_path / "config.json").write_text(json.dumps(rec))
        return stale_reason(cell, tmp_path)

    assert why(record) is None
    assert why({**record, "agent": {**record["agent"], "obs_mean": [0.5]}}) is None  # filled from the data
    assert why({**record, "agent": {k: v for k, v in record["agent"].items() if k != "dropout_rate"}}) is None
    old = why({k: v for k, v in record.items() if k != "agent_version"})  # recorded before versions: v1
    assert old == f"trained with bc v1; d5rl's bc is now v{get_agent('bc')[0].version}"
    other = why({**record, "agent": {**record["agent"], "actor_lr": 0.5}})
    assert other == f"trained with other settings: actor_lr 0.5 -> {r.agent.actor_lr!r}"
    frames = why({**record, "train": {**record["train"], "frame_stack": 4}})
    assert frames == "trained with other settings: frame_stack 4 -> 1"
    assert why({**record, "train": {**record["train"], "eval_episodes": 99}}) is None  # evaluation only
    custom = dataclasses.replace(cell, job=JOB)  # a custom job's config.json is its own business
    assert stale_agent(custom, tmp_path) is None


def test_a_report_of_only_stale_cells_says_so_and_writes_nothing(tmp_path):
    cells = expand_grid([TASK], ["bc"], [0, 1], 10, 0, job=JOB, tuned=False)
    run_bench(cells, tmp_path, workers=0, progress=False)
    for c in cells:
        _make_stale(c.directory(tmp_path))
    with pytest.raises(ReportError, match=r"every finished cell under .* is stale \(2; e\.g\. toy-reach-v0/bc/seed0"):
        write_report(tmp_path, reps=50, plots=False)
    assert not (tmp_path / "report").exists()  # no half-written report beside a stale one


def test_a_task_whose_cells_are_all_stale_keeps_its_row(tmp_path):
    cells = expand_grid([TASK, "toy-reach-pixels-v0"], ["bc"], [0], 10, 0, job=JOB, tuned=False)
    run_bench(cells, tmp_path, workers=0, progress=False)
    pixels = next(c for c in cells if c.task == "toy-reach-pixels-v0")
    _make_stale(pixels.directory(tmp_path))
    write_report(tmp_path, reps=50, plots=False)
    table = (tmp_path / "report" / "table1_offline.md").read_text()
    assert "| toy-reach-pixels-v0 | - |" in table  # waiting to be trained again, not gone
    assert f"| {TASK} | 0.250 ± 0.000 |" in table


def test_a_run_records_the_generator_inputs_its_data_was_made_from():
    from types import SimpleNamespace

    from d5rl.training.loop import _data_record

    ident = data_identity("a1-walk-v1")
    assert set(ident["generator_inputs"]) == {"speed-0.5-v1", "speed-0.8-v1", "speed-1.0-v1"}
    record = _data_record(SimpleNamespace(metadata={**ident, "task_id": "a1-walk-v1"}, num_episodes=5))
    assert record == {**ident, "episodes": 5}
    assert stale_data("a1-walk-v1", record) is None
    other = {**record, "generator_inputs": {**ident["generator_inputs"], "speed-0.8-v1": "0" * 64}}
    assert "other generator inputs than the published ones" in stale_data("a1-walk-v1", other)
    # a record made before runs kept the inputs cannot tell: not stale for that reason alone
    older = {k: v for k, v in record.items() if k != "generator_inputs"}
    assert stale_data("a1-walk-v1", older) is None
    assert stale_data("a1-walk-v1", {**older, "dataset_version": 0}) is not None
