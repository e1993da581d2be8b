"""An episode's camera frames for the browse page, as one image strip per camera (JPEG; PNG for tiny
frames): a grid of frames the page scrolls through, one request per camera, instant scrubbing.

Where frames come from, first that applies:

1. ``dataset`` — the dataset stores them (``observations/pixels/*`` arrays);
2. ``render cache`` — the camera task's render cache (``d5rl generate`` builds it) already holds
   the episode: read through :func:`load_dataset`, which then renders nothing;
3. ``rendered`` — rendered now from the episode's stored simulator states, by the family's
   per-episode renderer (``render_episode`` next to its ``DatasetSpec.derived`` builder: the very
   function that fills the render cache, same cameras and size) or, for families without one (A1), by
   replaying the states in the task's env (:mod:`d5rl.video`, fast quality).

Strips are cached under ``$D5RL_HOME/browse-cache/<dataset>/<version-seed>/<manifest digest>/`` and
written atomically; a regenerated dataset has another manifest digest, so stale frames are never
shown.  Rendering runs on one thread (a GL context belongs to the thread that made it).
"""

from __future__ import annotations

import hashlib
import importlib
import io
import json
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from d5rl import paths
from d5rl.browse.safe import inside
from d5rl.datasets import format as fmt
from d5rl.datasets.generation import dataset_root
from d5rl.datasets.loading import load_dataset
from d5rl.files import dump_json, write_atomic
from d5rl.registry import get_spec, make_replay_env, resolve
from d5rl.video import replay_frames

CACHE_DIR = "browse-cache"
MAX_STRIP_WIDTH = 8192  # pixels; browsers and JPEG handle far more, this keeps strips square-ish
ENV_VIEW_SIZE = (180, 240)  # (height, width) of frames replayed in an env (A1's track camera)
INDEX = "frames.json"
SMALL_FRAME = 48  # frames less tall than this are stored as PNG


class NoFrames(Exception):
    """The episode has no camera frames to show (no pixels and no simulator states in the dataset)."""


def camera_name(key: str) -> str:
    return key[len("observations/pixels/") :] if key.startswith("observations/pixels/") else key.split("/")[-1]


def pixel_keys(arrays) -> list[str]:
    return sorted(
        k
        for k, v in arrays.items()
        if k.startswith("observations/pixels") and len(v.shape) == 4 and v.shape[-1] == 3 and v.dtype == np.uint8
    )


def write_strip(path: Path, frames: np.ndarray) -> dict:
    """Tile ``frames (n, h, w, 3)`` row by row into one image at ``path`` (atomic; JPEG or PNG by the
    suffix); returns its layout."""
    from PIL import Image

    n, h, w = frames.shape[:3]
    cols = max(1, min(n, MAX_STRIP_WIDTH // w))
    rows = -(-n // cols)
    canvas = np.zeros((rows * h, cols * w, 3), np.uint8)
    for k in range(n):
        r, c = divmod(k, cols)
        canvas[r * h : (r + 1) * h, c * w : (c + 1) * w] = frames[k]
    buf = io.BytesIO()
    if path.suffix == ".png":
        Image.fromarray(canvas).save(buf, "PNG", optimize=False)
    else:
        Image.fromarray(canvas).save(buf, "JPEG", quality=90, subsampling=0)  # 4:4:4: colours of small objects
    write_atomic(path, buf.getvalue())
    return {"frames": int(n), "cols": int(cols), "width": int(w), "height": int(h)}


class Frames:
    """Frame strips of dataset episodes, made once and cached (see the module docstring)."""

    def __init__(self, datasets):
        self.datasets = datasets
        self._render = ThreadPoolExecutor(max_workers=1, thread_name_prefix="d5rl-browse-render")
        self._locks: dict[str, threading.Lock] = {}
        self._guard = threading.Lock()

    def close(self) -> None:
        self._render.shutdown(wait=False, cancel_futures=True)

    # --- where an episode's strips live ------------------------------------------------------------
    def episode_dir(self, task_id: str, index: int) -> Path:
        spec = get_spec(task_id)
        root = dataset_root(spec.dataset)
        digest = hashlib.sha256(json.dumps(fmt.read_manifest(root / fmt.MANIFEST), sort_keys=True).encode())
        base = paths.home() / CACHE_DIR
        return inside(base / spec.dataset.name / root.name / digest.hexdigest()[:16] / f"ep{int(index):06d}", [base])

    def strip_path(self, task_id: str, index: int, camera: str) -> Path:
        """The cached JPEG of one camera; :class:`KeyError` for a camera the episode does not have."""
        d = self.episode_dir(task_id, index)
        cams = {c["name"]: c for c in self._read_index(d)["cameras"]} if (d / INDEX).is_file() else {}
        if camera not in cams:
            raise KeyError(f"episode {index} of {task_id} has no camera {camera!r} (cameras: {sorted(cams)})")
        return inside(d / cams[camera]["file"], [d])

    @staticmethod
    def _read_index(d: Path) -> dict:
        return json.loads((d / INDEX).read_text())

    # --- making them -------------------------------------------------------------------------------
    def episode_frames(self, task_id: str, index: int) -> dict:
        """``{"source", "cameras": [{name, file, frames, cols, width, height}]}``, rendering if needed."""
        spec = get_spec(task_id)
        ds = self.datasets.get(spec.id)
        if not 0 <= index < ds.num_episodes:
            raise IndexError(f"episode {index} is not in {spec.id}'s dataset ({ds.num_episodes} episodes on disk)")
        d = self.episode_dir(spec.id, index)
        with self._guard:
            lock = self._locks.setdefault(str(d), threading.Lock())
        with lock:  # one maker per episode; later requests read what it wrote
            if (d / INDEX).is_file():
                idx = self._read_index(d)
                if all((d / c["file"]).is_file() for c in idx["cameras"]):
                    return idx
            source, frames = self._frames(spec, ds, index)
            d.mkdir(parents=True, exist_ok=True)
            cameras = []
            for key, arr in sorted(frames.items()):
                name = camera_name(key)
                arr = np.asarray(arr)
                # lossless for tiny frames (JPEG's 8x8 blocks would smear them), compact JPEG otherwise
                suffix = ".png" if arr.shape[1] < SMALL_FRAME else ".jpg"
                file = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name) + suffix
                cameras.append({"name": name, "file": file, **write_strip(d / file, arr)})
            idx = {"source": source, "cameras": cameras}
            dump_json(idx, d / INDEX)  # last: its presence means every strip is there
            return idx

    def _frames(self, spec, ds, index: int) -> tuple[str, dict[str, np.ndarray]]:
        ep = ds.episode(index)
        keys = pixel_keys(ep.arrays)
        if keys:
            return "dataset", {k: ep.arrays[k] for k in keys}
        if "states" not in ep.arrays:
            raise NoFrames(f"{spec.id}'s dataset stores neither camera frames nor simulator states")
        cached = render_cache_episode(spec, index)
        if cached is not None:
            return "render cache", cached
        return "rendered", self._render.submit(render_states, spec, ep.arrays["states"], ep.meta).result()


def render_cache_episode(spec, index: int) -> dict[str, np.ndarray] | None:
    """The episode's frames from the camera task's render cache, if that cache already covers it.

    The family's ``DatasetSpec.derived`` builder, asked for 0 episodes, names its cache directories
    and renders nothing; a cache shard counts as there when its record says it was rendered from the
    states of the dataset shard holding the episode.  Only then is the dataset loaded with its cache
    (:func:`load_dataset` re-checks every shard and would re-render only a damaged one).  Anything
    unexpected means "not cached": the caller renders the episode itself.
    """
    if spec.dataset is None or spec.dataset.derived is None or spec.observation != "pixels":
        return None

    try:
        root = dataset_root(spec.dataset)
        manifest = fmt.read_manifest(root / fmt.MANIFEST)
        caches = resolve(spec.dataset.derived)(spec, root, manifest, episodes=0, workers=1, progress=False)
        shards = [e for e in manifest["shards"] if e["episodes"][0] <= index]
        for cache in caches:
            for entry in shards:
                rec = fmt.read_shard_record(Path(cache) / entry["name"])
                if rec.get("source_states_sha256") != entry["arrays"]["states"]["sha256"]:
                    return None
        ds = load_dataset(
            spec, episodes=shards[-1]["episodes"][1], generate=False, progress=False, in_memory=False, workers=1
        )
        ep = ds.episode(index)
        keys = pixel_keys(ep.arrays)
        return {k: ep.arrays[k] for k in keys} or None
    except Exception:  # noqa: BLE001 (no cache, another format, a damaged record: render instead)
        return None


def render_states(spec, states: np.ndarray, meta: dict) -> dict[str, np.ndarray]:
    """Frames of one episode's stored states (run on the render thread)."""
    derived = spec.dataset.derived
    if derived:
        render_episode = getattr(importlib.import_module(derived.partition(":")[0]), "render_episode", None)
        if render_episode is not None:
            return render_episode({"states": np.asarray(states)}, meta)

    env = make_replay_env(spec.id, meta, render_mode="rgb_array")
    try:
        if not hasattr(env.unwrapped, "set_state"):
            raise NoFrames(f"{spec.id}'s environment cannot replay stored states")
        return {"observations/pixels/view": np.stack(list(replay_frames(env, states, ENV_VIEW_SIZE, "fast")))}
    finally:
        env.close()
