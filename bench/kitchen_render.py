"""Kitchen render speed: our render settings vs the stock scene, same run, same machine.

    MUJOCO_GL=egl nice -n 5 python bench/kitchen_render.py [--size 64] [--frames 200]

"stock" is the asset package's scene as shipped (8x MSAA, 4096 shadow maps, four
shadow-casting lights, full-resolution meshes) rendering the same camera and state.
"""

from __future__ import annotations

import argparse
import platform
import time

import mujoco

import d5rl  # noqa: F401  (sets MUJOCO_GL)
from d5rl.envs.kitchen import model as km
from d5rl.rendering import make_renderer


def fps(model: mujoco.MjModel, size: int, frames: int, camera: str) -> float:
    data = mujoco.MjData(model)
    data.qpos[:] = km.INIT_QPOS
    mujoco.mj_forward(model, data)
    r = make_renderer(model, size, size)
    r.update_scene(data, camera=camera)
    r.render()
    t = time.perf_counter()
    for _ in range(frames):
        r.update_scene(data, camera=camera)
        r.render()
    dt = time.perf_counter() - t
    r.close()
    return frames / dt


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--stock-frames", type=int, default=5)
    args = p.parse_args()
    ours = km.build_model()
    stock = km.stock_model()
    print(f"machine: {platform.processor() or platform.machine()}, mujoco {mujoco.__version__}, one process")
    print(f"triangles: ours {int(ours.mesh_facenum.sum())}, stock {int(stock.mesh_facenum.sum())}")
    for cam in ("overview", "wrist"):
        f_stock = fps(stock, args.size, args.stock_frames, cam)
        f_ours = fps(ours, args.size, args.frames, cam)
        print(
            f"{cam:9s} {args.size}x{args.size}: ours {f_ours:7.1f} fps | stock {f_stock:6.2f} fps | x{f_ours / f_stock:.0f}"
        )


if __name__ == "__main__":
    main()
