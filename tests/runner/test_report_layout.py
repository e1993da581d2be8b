"""The report's tables follow the paper's layout (row groups, method order) for any logs."""

import csv
import json

import numpy as np
import pytest

from d5rl.runner.grid import Cell
from d5rl.runner.report import write_report
from d5rl.training.rundir import RunDir

TASKS = ["wx-sorting-v0", "a1-walk-v0", "kitchen-standard-mixed-v0", "kitchen-randomized-demos-v0", "a1-run-v0"]
ALGOS = ["idql", "td3bc", "bc", "iql", "myalgo"]


def _fake_run(run_dir, rng):
    truth = {}
    for task in TASKS:
        for algo in ALGOS:
            for seed in range(3):
                cell = Cell(task, algo, seed, 100, 50 if algo != "bc" else 0)
                cdir = cell.directory(run_dir)
                RunDir(cdir).write_cell(cell.to_json())
                steps = [50, 100] + ([150] if cell.online_steps else [])
                scores = rng.uniform(-0.2, 1.1, len(steps))
                with open(cdir / "metrics.jsonl", "w") as f:  # the training loop's format
                    for s, sc in zip(steps, scores):
                        f.write(json.dumps({"step": s, "critic/loss": 1.0}) + "\n")
                        f.write(json.dumps({"step": s, f"eval/{task}/score": sc, f"eval/{task}/return": 3 * sc}) + "\n")
                (cdir / "done").write_text("{}")
                truth[(task, algo, seed)] = (scores[1], scores[2] if cell.online_steps else None)
    return truth


def test_paper_layout_and_numbers(tmp_path):
    truth = _fake_run(tmp_path, np.random.default_rng(0))
    write_report(tmp_path, reps=200, plots=False)
    md = (tmp_path / "report" / "table1_offline.md").read_text().splitlines()
    assert md[2] == "| Environment | Task | BC | IQL | TD3+BC | IDQL | myalgo |"
    rows = [line.split("|")[1:3] for line in md[4:]]
    assert [t.strip() for _, t in rows] == [
        "kitchen-standard-mixed-v0",
        "kitchen-randomized-demos-v0",
        "a1-run-v0",
        "a1-walk-v0",
        "wx-sorting-v0",
    ]
    assert [e.strip() for e, _ in rows] == ["Standard Kitchen", "Randomized Kitchen", "Locomotion", "", "WidowX"]
    with open(tmp_path / "report" / "table2_online.csv", newline="") as f:
        online = {r["task"]: r for r in csv.DictReader(f)}
    assert "bc_mean" not in next(iter(online.values()))  # BC ran offline only: not in Table 2
    for task in TASKS:
        for algo in ("iql", "td3bc", "idql", "myalgo"):
            vals = [truth[(task, algo, s)][1] for s in range(3)]
            assert float(online[task][f"{algo}_mean"]) == pytest.approx(np.mean(vals), abs=1e-12)
    agg = (tmp_path / "report" / "aggregate.md").read_text()
    assert "| BC | Locomotion | 2 | 6 |" in agg and "| IQL | all | 5 | 15 |" in agg


def test_tables_next_to_the_papers(tmp_path):
    truth = _fake_run(tmp_path, np.random.default_rng(1))
    write_report(tmp_path, reps=50, plots=False)
    md = (tmp_path / "report" / "table1_offline_vs_paper.md").read_text()
    header = next(line for line in md.splitlines() if line.startswith("| Environment |"))
    # every method of the paper's Table 1 is a column, run here or not, in the paper's order; then ours
    assert header == "| Environment | Task | BC | IQL | CQL | CalQL | TD3+BC | RLPD | DDPM+BC | IDQL | myalgo |"

    def entries(task):
        row = next(line for line in md.splitlines() if f"| {task} |" in line)
        return dict(zip(header.split("|")[3:-1], (c.strip() for c in row.split("|")[3:-1])))

    kitchen = entries("kitchen-standard-mixed-v0")
    bc = [truth[("kitchen-standard-mixed-v0", "bc", s)][0] for s in range(3)]
    assert kitchen[" BC "] == f"{np.mean(bc):.3f} ± {np.std(bc):.3f} / 0.461 ± 0.124"
    assert kitchen[" myalgo "].endswith("/ -")  # not in the paper
    assert kitchen[" RLPD "] == "- / 0.000 ± 0.000"  # not run here: ours "-", the paper's number kept
    assert entries("wx-sorting-v0")[" IDQL "].endswith("/ 0.173")  # the paper prints no ±
    assert entries("wx-sorting-v0")[" RLPD "] == "- / -"  # in neither
    online = (tmp_path / "report" / "table2_online_vs_paper.md").read_text()
    assert "0.935 ± 0.017" in online  # a1-walk IQL after fine-tuning


def test_a_task_the_paper_did_not_benchmark_keeps_its_row_next_to_the_papers(tmp_path):
    """The comparison has every task of the grid: one the paper has no row for is labelled so, "ours / -"."""
    for task, score in (("a1-walk-v0", 0.25), ("kitchen-randomized-suboptimal-state-v0", 0.5)):
        cell = Cell(task, "bc", 0, 100, 0)
        cdir = cell.directory(tmp_path)
        RunDir(cdir).write_cell(cell.to_json())
        (cdir / "metrics.jsonl").write_text(json.dumps({"step": 100, f"eval/{task}/score": score}) + "\n")
        (cdir / "done").write_text("{}")
    write_report(tmp_path, reps=50, plots=False)
    md = (tmp_path / "report" / "table1_offline_vs_paper.md").read_text()
    assert (
        "| Randomized Kitchen | kitchen-randomized-suboptimal-state-v0 (not in the paper) | 0.500 ± 0.000 / - |" in md
    )
    assert "| a1-walk-v0 | 0.250 ± 0.000 / 1.006 ± 0.015 |" in md
    only_toy = tmp_path / "toy"
    cell = Cell("toy-reach-v0", "bc", 0, 100, 0)
    RunDir(cell.directory(only_toy)).write_cell(cell.to_json())
    (cell.directory(only_toy) / "metrics.jsonl").write_text(
        json.dumps({"step": 100, "eval/toy-reach-v0/score": 1.0}) + "\n"
    )
    (cell.directory(only_toy) / "done").write_text("{}")
    write_report(only_toy, reps=50, plots=False)
    assert not (only_toy / "report" / "table1_offline_vs_paper.md").exists()  # no row of the paper's at all


def test_a_state_twin_is_compared_with_its_camera_task():
    from d5rl.runner.paper import paper_result

    assert paper_result("kitchen-randomized-partial-state-v0", "ddpm_bc", "offline") == (0.044, 0.010)
    assert paper_result("wx-sorting-state-v0", "rlpd", "offline") is None  # "-" in the paper
    assert paper_result("toy-reach-v0", "bc", "offline") is None


def test_the_papers_repeated_entries():
    """Entries the paper prints twice, mean and ±: TD3+BC's and RLPD's on A1 run and hiking (Table 1), and
    the Table 2 entries equal to their Table 1 entries (CQL on A1; CalQL, TD3+BC and IDQL on the kitchens)."""
    from d5rl.runner.paper import PAPER, paper_repeats

    assert paper_repeats("a1-run-v1", "td3bc", "offline") == ["rlpd"]
    assert paper_repeats("a1-hiking-v1", "rlpd", "offline") == ["td3bc"]
    assert paper_repeats("a1-walk-v1", "td3bc", "offline") == []  # 0.549 ± 0.178: its own
    assert paper_repeats("kitchen-standard-mixed-state-v0", "cql", "offline") == []  # 0.0 ± 0.0 says nothing
    assert paper_repeats("a1-walk-v1", "cql", "online") == ["offline"]
    assert paper_repeats("a1-walk-v1", "cql", "offline") == []  # the repeat is Table 2's
    assert paper_repeats("a1-walk-v1", "iql", "online") == []
    within = {(task, a) for task, row in PAPER["offline"].items() for a in row if paper_repeats(task, a, "offline")}
    assert within == {(t, a) for t in ("a1-run-v0", "a1-hiking-v0") for a in ("td3bc", "rlpd")}
    assert sum(bool(paper_repeats(t, a, "online")) for t, row in PAPER["online"].items() for a in row) == 14


def test_the_comparison_marks_the_papers_repeated_entries(tmp_path):
    _fake_run(tmp_path, np.random.default_rng(0))
    write_report(tmp_path, reps=50, plots=False)
    md = (tmp_path / "report" / "table1_offline_vs_paper.md").read_text()
    run_row = next(line for line in md.splitlines() if "| a1-run-v0 |" in line)
    assert "/ 0.002 ± 0.021† |" in run_row and "/ 0.684 ± 0.026 |" in run_row  # TD3+BC marked, BC not
    assert "† The paper's TD3+BC and RLPD entries on a1-run-v0 are the same, mean and ±" in md
    assert "a1-walk-v0" not in md.split("†")[-1]


def test_wall_time_counts_every_process(tmp_path):
    """A cell's wall time is its run's summed over the processes that ran it; for older runs that only know the
    last process's, the protocol table says it is a lower bound."""
    from d5rl.runner.results import collect
    from d5rl.runner.tables import protocol_markdown

    for seed, (summary, processes) in enumerate([({"run_wall_s": 600.0, "episodes": 5}, 2), ({"episodes": 5}, 1)]):
        cell = Cell("a1-walk-v0", "bc", seed, 100, 0)
        cdir = cell.directory(tmp_path)
        RunDir(cdir).write_cell(cell.to_json())
        (cdir / "metrics.jsonl").write_text(json.dumps({"step": 100, "eval/a1-walk-v0/score": 0.5}) + "\n")
        headers = [f"=== {cell.key} attempt 1 on vm pid {i} at now\n" for i in range(processes)]
        (cdir / "log.txt").write_text("".join(headers))
        (cdir / "done").write_text(json.dumps({"wall_s": 300.0, "summary": summary}))
    walls = sorted(c.wall_s for c in collect(tmp_path))
    assert walls == [300.0, 600.0]  # the run's total where known, not the last process's 300 s
    assert "| 7.5 min |" in protocol_markdown(collect(tmp_path))  # the median, no lower-bound mark
    (cell.directory(tmp_path) / "log.txt").write_text(f"=== {cell.key} attempt 1 a\n=== {cell.key} attempt 1 b\n")
    assert "| >= 7.5 min |" in protocol_markdown(collect(tmp_path))  # seed 1 was resumed: 300 s is its last process's


def test_what_the_agents_do_from_their_episode_stats(tmp_path):
    """The final evaluation's episode statistics (kitchen: which subtasks; the run's summary.json) are averaged
    per task and method; cells without them are left out of that table, not counted as zeros."""
    for algo, seed, stats in [
        ("bc", 0, {"subtask/microwave": 1.0, "subtask/slide_cabinet": 0.2}),
        ("bc", 1, {"subtask/microwave": 0.5, "subtask/slide_cabinet": 0.0}),
        ("bc", 2, None),
        ("iql", 0, {"subtask/microwave": 0.0}),
    ]:
        cell = Cell("kitchen-standard-mixed-state-v0", algo, seed, 100, 0)
        cdir = cell.directory(tmp_path)
        RunDir(cdir).write_cell(cell.to_json())
        (cdir / "metrics.jsonl").write_text(json.dumps({"step": 100, f"eval/{cell.task}/score": 0.5}) + "\n")
        (cdir / "done").write_text(json.dumps({"summary": {"episodes": 4}}))  # the job's summary keeps scalars only
        (cdir / "summary.json").write_text(json.dumps({"score": 0.5, **({"stats": stats} if stats else {})}))
    report = write_report(tmp_path, plots=False).read_text()
    assert "| Method | Cells | microwave | slide cabinet |" in report
    assert "| BC | 2 | 0.75 | 0.10 |" in report
    assert "| IQL | 1 | 0.00 | - |" in report


def test_an_entry_with_fewer_seeds_than_the_table_says_how_many(tmp_path):
    truth = _fake_run(tmp_path, np.random.default_rng(2))
    for seed in (1, 2):  # a1-walk IQL: seed 0 only; a1-run BC: seeds 0-1
        (Cell("a1-walk-v0", "iql", seed, 100, 50).directory(tmp_path) / "done").unlink()
    (Cell("a1-run-v0", "bc", 2, 100, 0).directory(tmp_path) / "done").unlink()
    write_report(tmp_path, reps=50, plots=False)
    for name in ("table1_offline.md", "table1_offline_vs_paper.md"):
        md = (tmp_path / "report" / name).read_text()
        rows = {
            line.split("|")[2].strip().split(" ")[0]: [c.strip() for c in line.split("|")[3:-1]]
            for line in md.splitlines()
            if "| a1-" in line
        }
        walk_iql = truth[("a1-walk-v0", "iql", 0)][0]
        assert rows["a1-walk-v0"][1].startswith(f"{walk_iql:.3f} ± 0.000 (n=1)")
        run_bc = [truth[("a1-run-v0", "bc", s)][0] for s in (0, 1)]
        assert rows["a1-run-v0"][0].startswith(f"{np.mean(run_bc):.3f} ± {np.std(run_bc):.3f} (n=2)")
        assert "(n=" not in rows["a1-walk-v0"][0] and "(n=" not in rows["a1-run-v0"][1]  # three seeds


def test_a_later_version_of_a_task_compares_with_the_papers_row(tmp_path):
    from d5rl.runner.paper import PAPER, paper_result, paper_task

    assert paper_task("a1-walk-v1") == "a1-walk-v0"  # the release's definition of the paper's walk
    assert paper_task("a1-hiking-smooth-v1") == "a1-hiking-v0"  # a data variant of a1-hiking-v1
    assert paper_task("a1-walk-v0") == "a1-walk-v0"
    assert paper_task("kitchen-standard-mixed-state-v0") == "kitchen-standard-mixed-v0"
    assert paper_task("toy-reach-v0") == "toy-reach-v0"  # not in the paper: itself
    assert paper_result("a1-run-v1", "bc", "offline") == PAPER["offline"]["a1-run-v0"]["bc"]
    assert paper_result("a1-run-v1", "calql", "online") == PAPER["online"]["a1-run-v0"]["calql"]

    def report(tasks):
        root = tmp_path / "+".join(tasks)
        for task in tasks:
            cell = Cell(task, "bc", 0, 100, 0)
            RunDir(cell.directory(root)).write_cell(cell.to_json())
            (cell.directory(root) / "metrics.jsonl").write_text(
                json.dumps({"step": 100, f"eval/{task}/score": 0.5}) + "\n"
            )
            (cell.directory(root) / "done").write_text("{}")
        write_report(root, reps=50, plots=False)
        return (root / "report" / "table1_offline_vs_paper.md").read_text()

    md = report(["a1-walk-v0", "a1-walk-v1"])
    assert "| a1-walk-v1 | 0.500 ± 0.000 / 1.006 ± 0.015 |" in md  # no "(paper: a1-walk-v0)": the same task
    assert "| a1-walk-v0 | 0.500 ± 0.000 / 1.006 ± 0.015 |" in md
    assert "A later version of a task (A1 v1" in md
    assert "A later version" not in report(["a1-walk-v0"])
