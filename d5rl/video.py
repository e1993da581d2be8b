"""Videos for people to watch (``d5rl render``, the browse page): frames of an env's render camera at
a chosen size and quality, encoded while they are rendered.

On a CPU (Mesa's llvmpipe) almost all of a frame's time goes into shadow maps (the A1 scene has
two lights with 4096² maps) and multisampling; ``quality="fast"`` turns both off (and planar
reflections), which keeps the scene recognizable at a several-fold higher frame rate
(``bench/render_video.py`` measures it).  ``quality="full"`` renders exactly like ``env.render()``.
Agents' camera observations never go through here: they keep the env's own renderers.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from d5rl.errors import D5RLError

QUALITIES = ("fast", "full")
VIDEO_SUFFIXES = (".mp4", ".mkv", ".mov", ".avi", ".gif")  # what write_video encodes (.webm silently fails)


def check_video_path(path: str | Path) -> Path:
    """A video's path, checked before anything is rendered: a container :func:`write_video` encodes, in
    a directory that can be written (created if missing)."""
    import os

    path = Path(path).expanduser()
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise D5RLError(
            f"cannot write a video to {path}: {path.suffix or 'no suffix'} is not one of {', '.join(VIDEO_SUFFIXES)}",
            f"pass e.g. {path.with_suffix('.mp4')}",
        )
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if not os.access(path.parent, os.W_OK):
            raise PermissionError(13, "Permission denied")
    except OSError as e:
        raise D5RLError(
            f"cannot write a video to {path} ({e.strerror or e})", "pass a path in a writable directory"
        ) from None
    return path


class FrameRenderer:
    """Callable returning the current frame ``uint8 (H, W, 3)`` of ``env``'s render camera.

    ``size`` is ``(height, width)`` (default: the env's ``render_size``).  One renderer is made here
    and reused for every frame; :meth:`close` frees it.  Envs without a MuJoCo render camera fall back
    to ``env.render()``.
    """

    def __init__(self, env, size: tuple[int, int] | None = None, quality: str = "fast"):
        if quality not in QUALITIES:
            raise ValueError(f"quality must be one of {QUALITIES}, got {quality!r}")
        self.env, self.base, self.renderer = env, env.unwrapped, None
        self.off: tuple = ()
        if not hasattr(self.base, "render_camera") or not hasattr(self.base, "model"):
            return
        import mujoco  # start-up time: MuJoCo and the GL backend load only for envs that render

        from d5rl.rendering import make_renderer  # start-up time, as mujoco

        h, w = size if size is not None else self.base.render_size
        vis = self.base.model.vis.quality
        samples = int(vis.offsamples)
        if quality == "fast":
            vis.offsamples = 0  # multisampling is fixed when the GL context is made: only for this renderer
        try:
            self.renderer = make_renderer(self.base.model, int(h), int(w))
        finally:
            vis.offsamples = samples
        if quality == "fast":
            self.off = (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION)

    def __call__(self) -> np.ndarray:
        if self.renderer is None:
            return self.env.render()
        self.renderer.update_scene(self.base.data, camera=self.base.render_camera)
        for flag in self.off:
            self.renderer.scene.flags[flag] = 0
        return self.renderer.render()

    def close(self) -> None:
        if self.renderer is not None:
            self.renderer.close()
            self.renderer = None


def write_video(path: str | Path, frames: Iterable[np.ndarray], fps: float) -> int:
    """Encode ``frames`` (an iterable, consumed as it is produced) into ``path``; returns the frame count.

    The encoder (ffmpeg, via imageio-ffmpeg) is a separate process fed through a pipe, so encoding
    runs on another core while the next frames render; the video is written to a temporary name and
    renamed into place, so a stopped render never leaves a truncated file behind.
    """
    import imageio.v2 as imageio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    n, complete = 0, False
    writer = imageio.get_writer(tmp, fps=fps, macro_block_size=1)
    try:
        for frame in frames:
            writer.append_data(frame)
            n += 1
        complete = True
    finally:
        writer.close()  # waits for ffmpeg to finish the file
        if complete:
            tmp.replace(path)
        else:
            tmp.unlink(missing_ok=True)
    return n


def write_gif(path: str | Path, frames, fps: float) -> None:
    """Write ``frames`` as a looping GIF, under a temporary name renamed into place."""
    import imageio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.gif")
    imageio.mimwrite(str(tmp), frames, duration=1000.0 / fps, loop=0)
    tmp.replace(path)


def replay_frames(env, states: np.ndarray, size=None, quality: str = "fast") -> Iterable[np.ndarray]:
    """Frames of stored simulator states replayed in ``env`` (one frame per state)."""
    render = FrameRenderer(env, size, quality)
    try:
        for state in states:
            env.unwrapped.set_state(state)
            yield render()
    finally:
        render.close()


def rollout_frames(env, steps: int, seed: int, size=None, quality: str = "fast") -> Iterable[np.ndarray]:
    """Frames of a uniformly random rollout: the first observation, then one per step until the episode
    ends or ``steps`` steps are done."""
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    env.action_space.seed(int(rng.integers(2**31)))
    render = FrameRenderer(env, size, quality)
    try:
        yield render()
        for _ in range(steps):
            _, _, term, trunc, _ = env.step(env.action_space.sample())
            yield render()
            if term or trunc:
                break
    finally:
        render.close()
