"""Shared test helpers for the training loop."""

import contextlib

from d5rl.training import loop


@contextlib.contextmanager
def interrupt_after_checkpoint(at_step: int):
    """Inside this block, the first checkpoint at or after ``at_step`` ends the run with KeyboardInterrupt,
    as a kill right after that checkpoint would."""
    real = loop.save_checkpoint

    def save(run_dir, ckpt):
        real(run_dir, ckpt)
        if ckpt.state["step"] >= at_step:
            raise KeyboardInterrupt(f"interrupted after the checkpoint at step {ckpt.state['step']}")

    loop.save_checkpoint = save
    try:
        yield
    finally:
        loop.save_checkpoint = real
