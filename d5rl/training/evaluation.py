"""Evaluation: run episodes in parallel environments with batched policy inference."""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any, Callable

import gymnasium as gym
import jax
import numpy as np

from d5rl.training.envs import env_factory, episode_scorer


def _stack_obs(obs_list):
    if isinstance(obs_list[0], dict):
        return {k: np.stack([o[k] for o in obs_list]) for k in obs_list[0]}
    return np.stack(obs_list)


def evaluate(
    agent,
    task_id: str,
    num_episodes: int = 10,
    seed: int = 0,
    *,
    num_envs: int = 1,
    frame_stack: int = 1,
    processes: bool = False,
    video_path: str | Path | None = None,
    env_fn: Callable[[], gym.Env] | None = None,
) -> dict[str, Any]:
    """Mean return, normalized score (if the task has references), success and length over episodes;
    ``stats``: the mean over episodes of each value of the final ``info["episode_stats"]``, where the
    task reports some (the kitchen: which subtasks were done).

    ``num_envs`` environments step in lockstep and the agent acts on all of them in
    one batch; ``processes=True`` puts each in its own process (gymnasium
    ``AsyncVectorEnv``).  Episode ``i`` resets with seed ``seed + i`` and a stochastic
    policy acts in it with keys drawn from ``(seed, i, step)``, so results do not depend
    on ``num_envs``.  ``video_path`` records the first episode.
    """
    if int(num_episodes) < 1:
        from d5rl.errors import D5RLError

        raise D5RLError(f"cannot evaluate on {num_episodes} episodes", "evaluate on at least 1 episode")
    num_envs = max(1, min(int(num_envs), int(num_episodes)))
    render = video_path is not None
    fns = [env_fn or env_factory(task_id, frame_stack, "rgb_array" if (render and i == 0) else None)
           for i in range(num_envs)]
    envs = [fn() for fn in fns] if not processes else None
    vec = gym.vector.AsyncVectorEnv([functools.partial(_in_worker, fn) for fn in fns], copy=True,
                                    context="spawn") if processes else None
    returns, lengths, successes, frames = [], [], [], []
    final_infos: list[dict] = []
    key = jax.random.PRNGKey(seed)
    ep = 0
    try:
        while ep < num_episodes:
            n = min(num_envs, num_episodes - ep)
            seeds = [seed + ep + i for i in range(n)]
            if processes:
                obs_b, _ = vec.reset(seed=seeds + [seed + 10**6 + i for i in range(num_envs - n)])
                obs = [jax.tree_util.tree_map(lambda x: x[i], obs_b) for i in range(n)]
            else:
                obs = [envs[i].reset(seed=s)[0] for i, s in enumerate(seeds)]
            done = np.zeros(n, bool)
            ret, length, succ = np.zeros(n), np.zeros(n, int), np.zeros(n, bool)
            last: list[dict] = [{} for _ in range(n)]
            if render and ep == 0:
                frames.append(_render(envs, vec, processes))
            while not done.all():
                live = np.flatnonzero(~done)
                batch = _stack_obs([obs[i] for i in live])
                keys = _step_keys(key, ep + live, length[live])
                actions = np.asarray(agent.eval_actions(batch, seed=keys))
                if processes:
                    full = np.zeros((num_envs,) + actions.shape[1:], np.float32)
                    full[live] = actions
                    obs_b, r, term, trunc, info = vec.step(full)
                    for j in live:
                        obs[j] = jax.tree_util.tree_map(lambda x: x[j], obs_b)
                        ret[j] += r[j]
                        length[j] += 1
                        s = info.get("success")
                        succ[j] |= bool(s[j]) if s is not None else False
                        done[j] = term[j] or trunc[j]
                        if done[j]:
                            last[j] = _unbatch_info(info, j)
                else:
                    for a, j in zip(actions, live):
                        obs[j], r, term, trunc, info = envs[j].step(a)
                        ret[j] += r
                        length[j] += 1
                        succ[j] |= bool(info.get("success", False))
                        done[j] = term or trunc
                        if done[j]:
                            last[j] = info
                if render and ep == 0 and not done[0]:
                    frames.append(_render(envs, vec, processes))
            returns += list(ret)
            lengths += list(length)
            successes += list(succ)
            final_infos += last
            ep += n
    except BaseException:
        if vec is not None:  # Ctrl-C or an error: stop the workers now, mid-step or not
            vec.close(terminate=True)
            vec = None
        raise
    finally:
        if vec is not None:
            vec.close()
        for e in envs or []:
            e.close()
    out = {"return": float(np.mean(returns)), "return_std": float(np.std(returns)),
           "length": float(np.mean(lengths)), "success": float(np.mean(successes)),
           "episodes": len(returns), "returns": [float(x) for x in returns]}
    stats = [info.get("episode_stats") or {} for info in final_infos]
    if any(stats):
        out["stats"] = {k: float(np.mean([st[k] for st in stats if k in st])) for k in sorted(set().union(*stats))}
    scorer = episode_scorer(task_id) if env_fn is None else None
    if scorer is not None:
        scores = np.asarray([scorer(r, info) for r, info in zip(returns, final_infos)], np.float64)
        out["score"] = float(scores.mean())
        out["score_std"] = float(scores.std())
    if render and frames:
        _write_video(Path(video_path), frames)
        out["video"] = str(video_path)
    return out


@jax.jit
def _step_keys(key, episodes, steps):
    """One key per (episode, step): a stochastic policy's action in episode ``i`` at step ``t`` is the same
    whichever episodes step beside it, so the result does not depend on ``num_envs``."""
    return jax.vmap(lambda e, t: jax.random.fold_in(jax.random.fold_in(key, e), t))(episodes, steps)


def _unbatch_info(info: dict, j: int) -> dict:
    """Environment ``j``'s part of a vector env's info (``score`` and ``episode_stats``, which evaluation reads)."""
    out: dict[str, Any] = {}
    if "score" in info:
        out["score"] = float(info["score"][j])
    if "episode_stats" in info:
        out["episode_stats"] = {k: float(v[j]) for k, v in info["episode_stats"].items() if not k.startswith("_")}
    return out


def _in_worker(make_env: Callable[[], gym.Env]) -> gym.Env:
    """Build an env inside an AsyncVectorEnv worker that dies with the evaluating process and leaves
    Ctrl-C to it (which then terminates the workers), so no worker outlives its evaluation."""
    import multiprocessing
    import signal

    from d5rl.parallel import die_with_parent

    if multiprocessing.parent_process() is not None:  # AsyncVectorEnv also calls this once in the parent
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        die_with_parent()
    return make_env()


def _render(envs, vec, processes):
    if processes:
        return np.asarray(vec.call("render")[0])
    return np.asarray(envs[0].render())


def _write_video(path: Path, frames) -> None:
    import imageio

    path.parent.mkdir(parents=True, exist_ok=True)
    fps = 20
    try:
        imageio.mimwrite(str(path), frames, fps=fps, macro_block_size=1)
    except Exception:  # noqa: BLE001 - no ffmpeg: fall back to GIF
        imageio.mimwrite(str(path.with_suffix(".gif")), frames, duration=1000 / fps)
