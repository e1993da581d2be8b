"""d5rl.video: the frames people watch (``d5rl render``, the browse page)."""

import numpy as np
import pytest

from d5rl.registry import make_env
from d5rl.video import FrameRenderer, write_video


def test_full_quality_is_env_render_and_fast_drops_shadows_only_in_its_own_renderer():
    env = make_env("a1-walk-v0", render_mode="rgb_array")
    env.reset(seed=0)
    base = env.unwrapped
    samples = int(base.model.vis.quality.offsamples)
    full, fast = FrameRenderer(env, (48, 64), "full"), FrameRenderer(env, (48, 64), "fast")
    try:
        # (a fresh full-quality context's very first frame differs in a few pixel values: compare the second)
        full(), base.render_camera_image(base.render_camera, 48, 64)
        a, b = full(), fast()
        assert a.shape == b.shape == (48, 64, 3)
        np.testing.assert_array_equal(a, base.render_camera_image(base.render_camera, 48, 64))
        assert np.abs(a.astype(int) - b.astype(int)).mean() > 1  # shadows and reflections gone
        assert int(base.model.vis.quality.offsamples) == samples  # the env's own renderers are untouched
        np.testing.assert_array_equal(full(), a)  # reused renderer, same frame
    finally:
        full.close(), fast.close(), env.close()
    with pytest.raises(ValueError, match="quality"):
        FrameRenderer(env, None, "ultra")


def test_write_video_is_atomic(tmp_path):
    def frames():
        yield np.zeros((16, 16, 3), np.uint8)
        raise KeyboardInterrupt

    out = tmp_path / "v.mp4"
    with pytest.raises(KeyboardInterrupt):
        write_video(out, frames(), fps=10)
    assert list(tmp_path.iterdir()) == []  # no truncated video, no temporary left
    assert write_video(out, (np.full((16, 16, 3), i, np.uint8) for i in range(5)), fps=10) == 5
    assert [p.name for p in tmp_path.iterdir()] == ["v.mp4"]
