"""Parallel evaluation (one process per env) never leaves workers behind: not on Ctrl-C, not on kill -9."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SCRIPT = """
import time, numpy as np
from d5rl.training.evaluation import evaluate

class Slow:
    started = False

    def eval_actions(self, obs, seed=None):
        if not self.started:
            print("start", flush=True)  # the workers are up and stepping
            self.started = True
        time.sleep(0.05)
        return np.zeros((len(obs), 2), np.float32)

evaluate(Slow(), "toy-reach-v0", 10_000, num_envs=2, processes=True)
"""


def _children(pid: int) -> list[int]:
    out = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        out += [int(x) for x in (task / "children").read_text().split()]
    return out


def _alive(pid: int) -> bool:
    try:
        return "\nState:\tZ" not in Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False


def _start():
    proc = subprocess.Popen(
        [sys.executable, "-c", SCRIPT],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        start_new_session=True,
    )
    assert proc.stdout.readline().strip() == "start"
    time.sleep(0.5)
    return proc, _children(proc.pid)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("how", ["sigkill", "ctrl-c"])
def test_eval_workers_do_not_outlive_the_evaluation(how):
    proc, kids = _start()
    assert len(kids) >= 2
    t0 = time.monotonic()
    if how == "sigkill":
        proc.kill()
    else:
        os.killpg(proc.pid, signal.SIGINT)
    proc.wait(timeout=30)
    assert time.monotonic() - t0 < 5.0
    deadline = time.time() + 5
    while time.time() < deadline and any(_alive(k) for k in kids):
        time.sleep(0.05)
    assert not [k for k in kids if _alive(k)]
    if how == "ctrl-c":
        err = proc.stderr.read()
        assert err.count("Traceback") <= 1, err[-3000:]  # the evaluator's KeyboardInterrupt only, not each worker's
