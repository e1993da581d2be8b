"""Frames/s of ``d5rl render`` now vs its previous implementation, same rollout, same run.

    python bench/render_video.py [--task a1-walk-v0] [--frames 40]

"old" is what ``d5rl render`` did before: ``env.render()`` at the task's render size with the
scene's full visuals (A1: two shadow-casting lights with 4096² shadow maps, 4x MSAA), every frame
kept in a list, then encoded in one go with ``imageio.mimsave``.  "new" is ``d5rl render``'s
pipeline (:mod:`d5rl.video`): one reused renderer at ``--quality fast`` (no shadows, reflections or
MSAA), frames streamed into ffmpeg while the next ones render.  Both render ``--frames`` frames of
the same seeded random rollout at the same size and write an MP4; wall time includes encoding.
Prints frames/s of both and the ratio new/old.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np

import d5rl  # noqa: F401  (sets MUJOCO_GL)
from d5rl.registry import make_env
from d5rl.video import rollout_frames, write_video


def old_render(task: str, steps: int, seed: int, out: str) -> int:
    """The previous ``d5rl render`` (random rollout branch), verbatim apart from the progress bar."""
    import imageio.v2 as imageio

    env = make_env(task, render_mode="rgb_array")
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    env.action_space.seed(int(rng.integers(2**31)))
    frames = [env.render()]
    for _ in range(steps):
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        frames.append(env.render())
        if term or trunc:
            break
    fps = env.unwrapped.metadata.get("render_fps", 20)
    env.close()
    imageio.mimsave(out, frames, fps=fps, macro_block_size=1)
    return len(frames)


def new_render(task: str, steps: int, seed: int, out: str) -> int:
    env = make_env(task, render_mode="rgb_array")
    try:
        return write_video(out, rollout_frames(env, steps, seed), fps=env.unwrapped.metadata.get("render_fps", 20))
    finally:
        env.close()


def timed(fn, *args) -> float:
    t0 = time.perf_counter()
    n = fn(*args)
    return n / (time.perf_counter() - t0)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="a1-walk-v0")
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    print(
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, MUJOCO_GL={os.environ.get('MUJOCO_GL')}"
    )
    with tempfile.TemporaryDirectory() as d:
        steps = args.frames - 1
        new_render(args.task, 2, args.seed, os.path.join(d, "warm.mp4"))  # GL and ffmpeg start-up, once
        old = timed(old_render, args.task, steps, args.seed, os.path.join(d, "old.mp4"))
        new = timed(new_render, args.task, steps, args.seed, os.path.join(d, "new.mp4"))
    print(
        f"{args.task}, {args.frames} frames: old {old:.2f} frames/s, new {new:.2f} frames/s, new/old {new / old:.1f}x"
    )


if __name__ == "__main__":
    main()
