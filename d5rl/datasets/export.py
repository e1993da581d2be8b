"""Export to the Minari format, so Minari-based code can train on d5rl data.

Needs the ``export`` extra (``pip install 'd5rl[export]'``).  The Minari
dataset lands in Minari's own root (``$MINARI_DATASETS_PATH`` or
``~/.minari/datasets``) and loads with ``minari.load_dataset(id)``.
Dict observation keys such as ``pixels/overview`` become ``pixels__overview``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d5rl.errors import D5RLError, MissingDependencyError
from d5rl.registry import get_spec, parse_task_id


def _space_for(arr: np.ndarray):
    import gymnasium as gym

    if np.issubdtype(arr.dtype, np.integer):
        info = np.iinfo(arr.dtype)
        return gym.spaces.Box(info.min, info.max, arr.shape[1:], arr.dtype)
    return gym.spaces.Box(-np.inf, np.inf, arr.shape[1:], arr.dtype)


def _minari_obs(ep_arrays: dict[str, np.ndarray]):
    if "observations" in ep_arrays:
        return ep_arrays["observations"]
    return {k[len("observations/"):].replace("/", "__"): v for k, v in ep_arrays.items() if k.startswith("observations/")}


def export_minari(task: str, *, dataset_id: str | None = None, seed: int | None = None,
                  episodes: int | None = None, progress: bool = True) -> Path:
    try:
        import gymnasium as gym
        import minari
        from minari.data_collector import EpisodeBuffer
    except ImportError as e:
        raise MissingDependencyError("Minari export needs the `minari` package",
                                     "pip install 'd5rl[export]'") from e
    from tqdm.auto import tqdm

    from d5rl.datasets.loading import load_dataset

    spec = get_spec(task)
    tid = parse_task_id(spec.id)
    dataset_id = dataset_id or f"d5rl/{tid.family}-{tid.name}-v{tid.version}"
    ds = load_dataset(spec, seed=seed, episodes=episodes, generate=False, progress=False)
    first = ds.episode(0).arrays
    obs0 = _minari_obs(first)
    if isinstance(obs0, dict):
        obs_space = gym.spaces.Dict({k: _space_for(v) for k, v in obs0.items()})
    else:
        obs_space = _space_for(obs0)
    act_space = _space_for(first["actions"])
    buffers = []
    for i, ep in enumerate(tqdm(ds.episodes(), total=ds.num_episodes, unit="ep", desc="export",
                                disable=not progress)):
        a = ep.arrays
        buffers.append(EpisodeBuffer(
            id=i, observations=_minari_obs(a), actions=a["actions"], rewards=a["rewards"].astype(np.float64),
            terminations=a["terminals"], truncations=a["timeouts"],
        ))
    try:
        md = minari.create_dataset_from_buffers(
            dataset_id=dataset_id,
            buffer=buffers,
            env=gym.spec(f"d5rl/{spec.id}"),  # `import d5rl` registers it, so minari can rebuild the env
            algorithm_name=ds.metadata.get("generator"),
            author="d5rl",
            code_permalink="https://pypi.org/project/d5rl/",
            observation_space=obs_space,
            action_space=act_space,
            ref_min_score=None if spec.score is None else spec.score.random,
            ref_max_score=None if spec.score is None else spec.score.expert,
            description=f"{spec.id}: {spec.description} (d5rl dataset {ds.metadata.get('dataset')} "
                        f"v{ds.metadata.get('dataset_version')}, seed {ds.metadata.get('seed')})",
        )
    except ValueError as e:
        raise D5RLError(f"Minari refused the export: {e}",
                        "pass another --dataset-id, or delete the existing Minari dataset") from e
    return Path(md.spec.data_path).parent
