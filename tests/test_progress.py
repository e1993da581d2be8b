"""Progress bars redraw ten times a second on a terminal, and at most every 30 s into a log file."""

import io
import sys

from d5rl import progress


def test_off_a_terminal_updates_are_rare(monkeypatch):
    log = io.StringIO()  # not a terminal, like a cell's log.txt
    monkeypatch.setattr(sys, "stderr", log)
    bar = progress.progress_bar(total=1000, desc="x", file=log, mininterval=1.0, dynamic_ncols=True)
    assert bar.mininterval == progress.LOG_INTERVAL
    for _ in range(1000):
        bar.update(1)
    bar.close()
    assert log.getvalue().count("\r") <= 3  # start, end (and at most one in between), not one per redraw


def test_on_a_terminal_the_bar_is_tqdms(monkeypatch):
    class Tty(io.StringIO):
        def isatty(self):
            return True

    tty = Tty()
    monkeypatch.setattr(sys, "stderr", tty)
    bar = progress.progress_bar(total=10, mininterval=0.5, file=tty)
    assert bar.mininterval == 0.5
    bar.close()


def test_every_command_takes_no_progress(capsys):
    """`--no-progress` is one switch on every command; it hides the bars of that command only."""
    from d5rl.cli import build_parser, main
    from tests.datasets.toy import register_toy

    commands = build_parser()._subparsers._group_actions[0].choices
    assert all("--no-progress" in q._option_string_actions for q in commands.values())

    spec = register_toy("quiet", num_episodes=4, per_shard=2)
    assert main(["generate", spec.id, "--workers", "1", "--no-progress"]) == 0
    assert "%|" not in capsys.readouterr().err
    assert progress._enabled  # restored for whatever runs next in this process
    assert main(["generate", spec.id, "--workers", "1", "--force"]) == 0
    assert "%|" in capsys.readouterr().err  # without the switch the same command draws its bar
