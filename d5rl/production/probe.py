"""Nearest-neighbour imitation: can a state task's data be followed closed-loop at all?

A k-nearest-neighbour policy acts with the mean action of the ``k`` dataset observations closest
to the current one (each dimension standardised with the dataset's mean and std).  It has no
parameters and no training budget, so its score separates two questions a low agent score
leaves open: is the data hard to imitate from these observations (then this probe fails too),
or do the agents not fit it (then the probe scores well and they do not)?

    python -m d5rl.production.probe kitchen-standard-mixed-state-v0 --episodes 20 --k 5

State observations only (a pixel task's images are not a useful metric space for this).
Needs scipy (installed with the ``train`` extra, through jax).
"""

from __future__ import annotations

import argparse

import numpy as np

from d5rl.datasets.loading import load_dataset
from d5rl.errors import D5RLError
from d5rl.training.evaluation import evaluate


class NearestNeighbourPolicy:
    """Mean action of the ``k`` nearest dataset observations (standardised Euclidean distance)."""

    def __init__(self, observations: np.ndarray, actions: np.ndarray, k: int = 5):
        try:
            from scipy.spatial import cKDTree
        except ImportError as e:  # pragma: no cover - scipy comes with jax
            raise D5RLError("the nearest-neighbour probe needs scipy", "pip install 'd5rl[train]'") from e
        if isinstance(observations, dict) or np.ndim(observations) != 2:
            raise D5RLError(
                f"the probe needs flat state observations, got shape {np.shape(observations)}",
                "use a task's -state twin (e.g. kitchen-standard-mixed-state-v0)",
            )
        observations = np.asarray(observations, np.float64)
        if not 1 <= int(k) <= len(observations):
            raise D5RLError(
                f"k={k} is not between 1 and the {len(observations)} dataset observations", "pass a smaller --k"
            )
        self.k = int(k)
        self.mean = observations.mean(0)
        self.std = observations.std(0) + 1e-6
        self.actions = np.asarray(actions, np.float32)
        self.tree = cKDTree((observations - self.mean) / self.std)

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        obs = (np.atleast_2d(np.asarray(observations, np.float64)) - self.mean) / self.std
        _, idx = self.tree.query(obs, k=self.k)
        idx = idx.reshape(len(obs), self.k)
        return self.actions[idx].mean(axis=1)

    def eval_actions(self, observations, seed=None) -> np.ndarray:  # the agents' evaluation interface
        return self(observations)


def probe(task_id: str, episodes: int = 20, k: int = 5, seed: int = 0, num_envs: int = 5) -> dict:
    """Evaluate the nearest-neighbour policy of ``task_id``'s dataset; :func:`evaluate`'s result."""
    ds = load_dataset(task_id)
    policy = NearestNeighbourPolicy(ds.observations, ds.arrays["actions"], k)
    return evaluate(policy, task_id, episodes, seed, num_envs=num_envs)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(prog="python -m d5rl.production.probe", description=__doc__.split("\n\n")[0])
    p.add_argument("task", help="a state task (kitchen and WidowX: their -state twins)")
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--k", type=int, default=5, help="neighbours averaged per action")
    p.add_argument("--seed", type=int, default=0, help="episode i resets with seed + i")
    args = p.parse_args(argv)
    r = probe(args.task, args.episodes, args.k, args.seed)
    score = f"score {r['score']:.3f} ± {r['score_std']:.3f}, " if "score" in r else ""
    print(
        f"{args.task}: {args.k}-nearest-neighbour policy over {r['episodes']} episodes: {score}"
        f"return {r['return']:.1f} ± {r['return_std']:.1f}"
    )
    for k, v in r.get("stats", {}).items():
        print(f"  {k}: {v:.2f}")


if __name__ == "__main__":
    main()
