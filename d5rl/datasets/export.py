"""Export to the Minari format, so Minari-based code can train on d5rl data.

Needs the ``export`` extra (``pip install 'd5rl[export]'``).  The Minari dataset lands in
Minari's own root (``$MINARI_DATASETS_PATH``, else ``~/.minari/datasets``) and loads with
``minari.load_dataset(id)``.  The export is lossless and describes the task's environment:

- observations and actions are stored as they are (no JPEG: Minari's default for images is
  lossy, so it is switched off), with the environment's own observation and action spaces;
- Minari's HDF5 storage cannot hold Dict keys containing ``/`` (it nests them as groups), so
  ``pixels/side`` is stored as ``pixels__side`` (:func:`minari_key`), and the environment that
  ``dataset.recover_environment()`` builds applies the same renaming (:class:`MinariKeys`), so
  its observations match the stored ones key for key.  :func:`d5rl_key` maps back.
- the environment id (``d5rl/a1-walk-minari-v0``) is registered with Gymnasium when d5rl is imported,
  so ``gymnasium.make(dataset.spec.env_spec.id)`` works as for any Minari dataset;
- the dataset's ``infos/*`` arrays (forward speed, subtasks completed, stage, ...) are the episodes'
  ``infos``, so a task's score can be computed from the Minari file alone.  Minari's infos have one row
  per observation (the reset's, then each step's); d5rl stores most infos per transition, so their row 0
  (the reset's) is zeros.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np

from d5rl.datasets.loading import load_dataset
from d5rl.errors import D5RLError, MissingDependencyError
from d5rl.progress import progress_bar
from d5rl.registry import get_spec, minari_env_id, parse_task_id, resolve

SEP = "__"


def minari_key(key: str) -> str:
    """d5rl observation key -> the key stored in a Minari dataset (``pixels/side`` -> ``pixels__side``)."""
    return key.replace("/", SEP)


def d5rl_key(key: str) -> str:
    """The inverse of :func:`minari_key`."""
    return key.replace(SEP, "/")


class MinariKeys(gym.ObservationWrapper):
    """Renames Dict observation keys with :func:`minari_key` (the environment of exported datasets)."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        space = env.observation_space
        if isinstance(space, gym.spaces.Dict):
            self.observation_space = gym.spaces.Dict({minari_key(k): v for k, v in space.spaces.items()})

    def observation(self, obs):
        return {minari_key(k): v for k, v in obs.items()} if isinstance(obs, dict) else obs


def make_minari_env(task_id: str, **kwargs) -> gym.Env:
    """Entry point of the environment spec stored with an export (the task's env, keys renamed).
    The time limit comes from the spec, as for every Gymnasium id."""
    spec = get_spec(task_id)
    return MinariKeys(resolve(spec.entry_point)(**{**spec.env_kwargs, **kwargs}))


def minari_env_spec(task_id: str) -> gym.envs.registration.EnvSpec:
    spec = get_spec(task_id)
    return gym.envs.registration.EnvSpec(
        id=minari_env_id(spec.id),
        entry_point="d5rl.datasets.export:make_minari_env",
        kwargs={"task_id": spec.id},
        max_episode_steps=spec.max_episode_steps,
        disable_env_checker=True,
    )


def _episode_obs(arrays: dict[str, np.ndarray], space: gym.Space):
    if isinstance(space, gym.spaces.Dict):
        return {k: arrays["observations/" + d5rl_key(k)] for k in space.spaces}
    return arrays["observations"]


def _episode_infos(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``infos/<name>`` arrays with one row per observation, as Minari stores them (see the module docstring)."""
    n_obs = len(arrays["actions"]) + 1
    out = {}
    for key, v in arrays.items():
        if key.startswith("infos/"):
            v = np.asarray(v)
            if len(v) == n_obs - 1:
                v = np.concatenate([np.zeros((1,) + v.shape[1:], v.dtype), v])
            out[minari_key(key[len("infos/") :])] = v
    return out


def _check(name: str, values: np.ndarray, space: gym.spaces.Box, what: str) -> None:
    if values.shape[1:] != space.shape or values.dtype != space.dtype:
        raise D5RLError(
            f"{what}: the dataset's {name} are {values.dtype}{values.shape[1:]}, the environment's "
            f"space is {space.dtype}{space.shape}",
            "export the dataset at the environment's image size (the render cache's default)",
        )
    if np.issubdtype(values.dtype, np.floating) and not np.isfinite(values).all():
        raise D5RLError(f"{what}: the dataset's {name} hold NaN or infinite values", "run `d5rl verify` on it")
    if np.isfinite(space.low).all() and np.isfinite(space.high).all():
        if (values < space.low).any() or (values > space.high).any():
            raise D5RLError(
                f"{what}: the dataset's {name} leave the environment's bounds [{space.low.min()}, {space.high.max()}]",
                "report this to the d5rl maintainers",
            )


def export_minari(
    task: str,
    *,
    dataset_id: str | None = None,
    seed: int | None = None,
    episodes: int | None = None,
    progress: bool = True,
) -> Path:
    try:
        import minari
        from minari.data_collector import EpisodeBuffer
    except ImportError as e:
        raise MissingDependencyError("Minari export needs the `minari` package", "pip install 'd5rl[export]'") from e

    spec = get_spec(task)
    tid = parse_task_id(spec.id)
    dataset_id = dataset_id or f"d5rl/{tid.family}-{tid.name}-v{tid.version}"
    env_spec = minari_env_spec(spec.id)
    env = gym.make(env_spec)
    obs_space, act_space = env.observation_space, env.action_space
    env.close()
    ds = load_dataset(spec, seed=seed, episodes=episodes, generate=False, progress=False)
    buffers = []
    for i, ep in enumerate(
        progress_bar(ds.episodes(), total=ds.num_episodes, unit="ep", desc="export", disable=not progress)
    ):
        a = ep.arrays
        obs = _episode_obs(a, obs_space)
        for k, v in obs.items() if isinstance(obs, dict) else [("observations", obs)]:
            _check(f"observations {k!r}", v, obs_space[k] if isinstance(obs, dict) else obs_space, f"episode {i}")
        _check("actions", a["actions"], act_space, f"episode {i}")
        buffers.append(
            EpisodeBuffer(
                id=i,
                observations=obs,
                actions=a["actions"],
                rewards=a["rewards"].astype(np.float64),
                terminations=a["terminals"],
                truncations=a["timeouts"],
                infos=_episode_infos(a) or None,
            )
        )
    try:
        with warnings.catch_warnings():  # d5rl has no contact address to give; everything else is filled in
            warnings.filterwarnings("ignore", message="`author_email` is set to None", category=UserWarning)
            md = minari.create_dataset_from_buffers(
                dataset_id=dataset_id,
                buffer=buffers,
                env=env_spec,
                eval_env=env_spec,
                algorithm_name=ds.metadata.get("generator"),
                author="d5rl",
                code_permalink="https://pypi.org/project/d5rl/",
                observation_space=obs_space,
                action_space=act_space,
                ref_min_score=None if spec.score is None else spec.score.random,
                ref_max_score=None if spec.score is None else spec.score.expert,
                description=f"{spec.id}: {spec.description} (d5rl dataset {ds.metadata.get('dataset')} "
                f"v{ds.metadata.get('dataset_version')}, seed {ds.metadata.get('seed')}; Dict keys use "
                f"'{SEP}' for '/')",
                jpeg_encoding=False,
            )
    except ValueError as e:
        raise D5RLError(
            f"Minari refused the export: {e}", "pass another --dataset-id, or delete the existing Minari dataset"
        ) from e
    return Path(md.spec.data_path).parent
