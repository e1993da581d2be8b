"""The docs' result tables are copied from the reports by ``python -m tests.mdtables`` (``sync``)."""

from tests.mdtables import doc_tables, sync

REPORT = """### Table 1: offline (ours / paper)

| Environment | Task | BC | IQL |
|---|---|---|---|
| Locomotion | a1-walk-v1 | 0.500 ± 0.010 / 1.006 ± 0.015 | 0.700 ± 0.020 (n=2) / 0.962 ± 0.007 |
"""

PAGE = """# Results

Intro with a [report](docs/results/g/report.md).

| Environment | Task | BC | IQL |
|---|---|---|---|
| Locomotion | a1-walk-v1 | 0.400 ± 0.010 / 1.006 ± 0.015 (seed 2 falls) | 0.700 ± 0.020 (n=2) / 0.962 ± 0.007 (a remark) |

Text after the table.
"""


def _root(tmp_path):
    grid = tmp_path / "docs" / "results" / "g"
    grid.mkdir(parents=True)
    (grid / "table1_offline_vs_paper.md").write_text(REPORT)
    (tmp_path / "README.md").write_text(PAGE)
    return tmp_path


def test_sync_copies_the_entries_that_disagree_and_keeps_the_rest(tmp_path):
    root = _root(tmp_path)
    (table,) = doc_tables(root)
    assert table.grid == "g" and table.reported[("a1-walk-v1", "BC")] == "0.500 ± 0.010 / 1.006 ± 0.015"

    assert sync(root, write=False) == [
        "README.md: a1-walk-v1 BC: 0.400 ± 0.010 / 1.006 ± 0.015 (seed 2 falls) -> 0.500 ± 0.010 / 1.006 ± 0.015"
    ]
    assert (root / "README.md").read_text() == PAGE  # write=False only reports

    assert len(sync(root)) == 1
    text = (root / "README.md").read_text()
    assert (
        "| Locomotion | a1-walk-v1 | 0.500 ± 0.010 / 1.006 ± 0.015 | 0.700 ± 0.020 (n=2) / 0.962 ± 0.007 (a remark) |"
        in text
    )
    assert text.startswith("# Results\n") and text.endswith("\nText after the table.\n")
    assert sync(root) == []  # agrees now; nothing written again


def test_a_table_after_no_grid_link_is_left_alone(tmp_path):
    root = _root(tmp_path)
    (root / "README.md").write_text(PAGE.replace("[report](docs/results/g/report.md)", "no link"))
    (table,) = doc_tables(root)
    assert table.grid is None and table.reported == {}
    assert sync(root) == []
