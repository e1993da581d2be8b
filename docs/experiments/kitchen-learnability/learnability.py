"""Why do BC and IQL from state fail on the scripted standard-kitchen data? Seven experiments.

    python docs/experiments/kitchen-learnability/learnability.py            # E1 to E7
    python docs/experiments/kitchen-learnability/learnability.py --only e3  # one of them

on the registered ``kitchen-standard`` dataset (generated on first use; ``d5rl generate
kitchen-standard-mixed-state-v0``).  Each prints a Markdown table; README.md next to this file holds
the numbers and what they say.

E1  BC (d5rl's agent with the settings ``d5rl train bc kitchen-standard-mixed-state-v0`` uses) trained
    on the episodes whose first subtask is X, and on all of them; evaluated on the mixed task.  Does
    the choice between first subtasks, all from one start state, defeat a unimodal Gaussian?
E2  The k-nearest-neighbour policy (:mod:`d5rl.production.probe`) on the same data: is the information
    needed to act in the 30 joint positions?
E3  Action fit on held-out episodes (every 10th), split by the demonstrator's phase: approach
    (pre-grasp, reach), manipulation (grasp to release) and transition (joint-space transits between
    subtasks, retreats).  Phases are not stored in the data: the held-out episodes are generated again
    with the demonstrator's phase recorded, and their actions are checked to equal the stored ones.
E4  BC with batches drawn as if the orders followed an operator's habit (``order_probabilities``).
E5  BC on data generated with that habit (``KitchenStandardGenerator(habit=...)``, a task registered
    here), next to BC on as many episodes of the dataset.
E6  BC on data whose demonstrator slips off course now and then and corrects
    (``KitchenStandardGenerator(slips=...)``): do corrections keep BC on the data's states?
E7  BC on one order of subtasks (habit 1) with the demonstrator's action noise scaled: is the spread of
    states what BC lacks to chain subtasks?
"""

from __future__ import annotations

import argparse
import time

import numpy as np

TASK = "kitchen-standard-mixed-state-v0"
PHASE_GROUPS = {
    "approach": ("pre-grasp", "pre-push", "reach"),
    "manipulation": ("grasp", "swing", "slide", "turn", "push", "lift", "carry", "lower", "release"),
    "transition": ("transit", "retreat"),
}
HELD_OUT_EVERY = 10  # E3: episodes 0, 10, 20, ... are held out


def train_bc(observations, actions, seed: int, steps: int, chunk: int = 100, weights=None):
    """BC with the settings `d5rl train bc TASK --offline-steps steps` resolves (batches drawn uniformly,
    or with probabilities ``weights`` per transition)."""
    from d5rl.agents.bc import BCAgent
    from d5rl.settings import resolve

    cfg = resolve("bc", TASK, offline_steps=steps).agent
    agent = BCAgent.create(seed, observations[:1], actions[:1], cfg)
    rng = np.random.default_rng(seed)
    for _ in range(steps // chunk):
        if weights is None:
            b = rng.integers(0, len(observations), (chunk, cfg.batch_size))
        else:
            b = rng.choice(len(observations), (chunk, cfg.batch_size), p=weights)
        agent, _ = agent.update_many({"observations": observations[b], "actions": actions[b]})
    return agent


def bc_columns(x, y, seeds, steps: int, episodes: int, weights=None) -> str:
    """BC trained on ``(x, y)`` once per seed and evaluated on ``episodes`` of the mixed task: the table
    columns "score per seed | mean | subtasks done" (subtask rates averaged over the seeds)."""
    from d5rl.training.evaluation import evaluate

    scores, stats = [], {}
    for seed in seeds:
        r = evaluate(train_bc(x, y, seed, steps, weights=weights), TASK, episodes, seed=seed, num_envs=5)
        scores.append(r["score"])
        for k, v in r.get("stats", {}).items():
            stats[k] = stats.get(k, 0.0) + v / len(seeds)
    per_seed = ", ".join(f"{s:.3f}" for s in scores)
    return f"{per_seed} | {np.mean(scores):.3f} | {_subtask_cols(stats)}"


def load(episodes: int | None):
    from d5rl.datasets.loading import load_dataset

    ds = load_dataset(TASK, episodes=episodes, progress=False)
    obs = np.asarray(ds.observations, np.float32)
    act = np.asarray(ds.arrays["actions"], np.float32)
    return ds, obs, act


def first_subtasks(ds) -> np.ndarray:
    return np.array([m["subtasks"][0] for m in ds.episode_meta])


def _subtask_cols(stats: dict) -> str:
    names = ("microwave", "kettle", "bottom_burner", "top_burner", "light_switch", "slide_cabinet", "hinge_cabinet")
    return " / ".join(f"{stats.get(f'subtask/{n}', 0.0):.2f}" for n in names)


def e1(ds, obs, act, seeds, steps, episodes) -> None:

    first = first_subtasks(ds)
    subsets = [("all", np.ones(len(first), bool))]
    for name in dict.fromkeys(first):  # in order of appearance
        subsets.append((f"first subtask {name}", first == name))
    combos = np.array([" > ".join(m["subtasks"]) for m in ds.episode_meta])
    top = max(set(combos), key=lambda c: (np.sum(combos == c), c))
    subsets.append((f"one order: {top}", combos == top))
    print(f"\nE1: BC {steps} steps on episodes by first subtask; {episodes} evaluation episodes of {TASK} per seed")
    print(
        "| episodes used | episodes | score per seed | mean | subtasks done (mw / kettle / bb / tb / light / slide / hinge) |"
    )
    print("|---|---:|---|---:|---|")
    for what, keep in subsets:
        rows = np.flatnonzero(keep[ds.transition_episode])
        cols = bc_columns(obs[rows], act[rows], seeds, steps, episodes)
        print(f"| {what} | {keep.sum()} | {cols} |", flush=True)


def e2(ds, obs, act, ks, episodes) -> None:
    from d5rl.production.probe import NearestNeighbourPolicy
    from d5rl.training.evaluation import evaluate

    print(f"\nE2: k-nearest-neighbour policy on all {len(ds.episode_lengths)} episodes, {episodes} evaluation episodes")
    print("| policy | score (mixed) | subtasks done (mw / kettle / bb / tb / light / slide / hinge) |")
    print("|---|---|---|")
    for k in ks:
        r = evaluate(NearestNeighbourPolicy(obs, act, k), TASK, episodes, seed=0, num_envs=5)
        print(f"| {k}-NN | {r['score']:.3f} ± {r['score_std']:.3f} | {_subtask_cols(r['stats'])} |", flush=True)


def phase_labels(episodes: list[int], stored_actions: list[np.ndarray]) -> list[np.ndarray]:
    """The demonstrator's phase at every step of ``episodes``, by generating them again (checked: the
    same actions as stored)."""
    from d5rl.datasets.generation import episode_rng, make_generator
    from d5rl.production.kitchen import demonstrator as dm
    from d5rl.registry import get_spec

    spec = get_spec(TASK)
    seed = spec.dataset.default_seed
    gen = make_generator(TASK)
    act_original = dm.Demonstrator.act
    record: list[str] = []

    def act(self):
        a = act_original(self)
        record.append("hold" if self._phase is None else self._phase.name)
        return a

    out = []
    dm.Demonstrator.act = act
    try:
        for i, stored in zip(episodes, stored_actions):
            record.clear()
            ep = gen.episode(i, episode_rng(seed, i))
            if not np.array_equal(ep.arrays["actions"], stored):
                raise SystemExit(f"episode {i} generated again differs from the stored one: other code or CPU")
            out.append(np.array(record[: len(stored)]))
    finally:
        dm.Demonstrator.act = act_original
    return out


def e3(ds, obs, act, seeds, steps) -> None:
    from d5rl.production.probe import NearestNeighbourPolicy

    n_eps = len(ds.episode_lengths)
    held = np.arange(0, n_eps, HELD_OUT_EVERY)
    held_rows = np.isin(ds.transition_episode, held)
    starts = np.concatenate([[0], np.cumsum(ds.episode_lengths)])
    phases = phase_labels(list(held), [act[starts[i] : starts[i + 1]] for i in held])
    phase = np.concatenate(phases)
    group = np.full(len(phase), "other", dtype=object)
    for g, names in PHASE_GROUPS.items():
        group[np.isin(phase, names)] = g
    x, y = obs[held_rows], act[held_rows]
    arm = slice(0, 7)  # the two finger actions are always +-1: the fit of the arm's 7 joints

    def mse(pred):
        return ((pred[:, arm] - y[:, arm]) ** 2).sum(-1)

    preds = {}
    for seed in seeds:
        agent = train_bc(obs[~held_rows], act[~held_rows], seed, steps)
        preds[f"BC seed {seed}"] = np.asarray(agent.eval_actions(x))
    train_x, train_y = obs[~held_rows], act[~held_rows]
    for k in (1, 5):
        preds[f"{k}-NN"] = NearestNeighbourPolicy(train_x, train_y, k)(x)
    preds["mean action"] = np.broadcast_to(train_y.mean(0), y.shape)
    cols = ["all", *PHASE_GROUPS]
    print(
        f"\nE3: arm action squared error (sum over 7 joints) on {len(held)} held-out episodes "
        f"({len(y):,} steps); BC {steps} steps on the other {n_eps - len(held)}"
    )
    share = " / ".join(f"{g} {np.mean(group == g):.0%}" for g in PHASE_GROUPS)
    print(f"steps by phase: {share}")
    print("| predictor | " + " | ".join(cols) + " |")
    print("|---|" + "---:|" * len(cols))
    for name, p in preds.items():
        e = mse(p)
        vals = [e.mean()] + [e[group == g].mean() for g in PHASE_GROUPS]
        print(f"| {name} | " + " | ".join(f"{v:.3f}" for v in vals) + " |", flush=True)


def e4(ds, obs, act, habits, seeds, steps, episodes) -> None:
    """BC with batches drawn as if the data's orders followed an operator's habit (probability ``p`` of
    the habitual next subtask at every choice): what a demonstrator with that habit would teach."""
    from d5rl.production.kitchen.data import COMBINATIONS, order_probabilities

    combo = np.array([COMBINATIONS.index(tuple(m["subtasks"])) for m in ds.episode_meta])
    counts = np.bincount(combo, minlength=len(COMBINATIONS))
    print(f"\nE4: BC {steps} steps, episodes weighted to the habit's order distribution; {episodes} episodes of {TASK}")
    print(
        "| habit p | first subtask microwave | microwave then kettle | score per seed | mean | subtasks done (mw / kettle / bb / tb / light / slide / hinge) |"
    )
    print("|---|---:|---:|---|---:|---|")
    for p in habits:
        probs = np.asarray(order_probabilities(p))
        w_ep = probs[combo] / counts[combo]
        w = w_ep[ds.transition_episode] / ds.episode_lengths[ds.transition_episode]
        w = w / w.sum()
        mw = sum(q for c, q in zip(COMBINATIONS, probs) if c[0] == "microwave")
        mwk = sum(q for c, q in zip(COMBINATIONS, probs) if c[:2] == ("microwave", "kettle"))
        cols = bc_columns(obs, act, seeds, steps, episodes, weights=w)
        print(f"| {p} | {mw:.0%} | {mwk:.0%} | {cols} |", flush=True)


def variant_task(tag: str, description: str, **generator_kwargs) -> str:
    """A state task like the mixed one on data of the standard kitchen's generator with other arguments
    (``KitchenStandardGenerator(**generator_kwargs)``; its own dataset directory, portable numerics)."""
    import dataclasses

    from d5rl.registry import get_spec, register

    base = get_spec(TASK)
    dspec = dataclasses.replace(
        base.dataset,
        name=f"kitchen-standard-{tag}",
        generator_kwargs=generator_kwargs,
        numerics="portable",
        description=f"kitchen-standard's demonstrator, {description}",
    )
    tid = f"kitchen-standard-mixed-state-{tag}-v0"
    register(dataclasses.replace(base, id=tid, dataset=dspec, dataset_variants={}))
    return tid


def habit_task(habit: float) -> str:
    """Data whose combinations follow an operator with ``habit`` (``KitchenStandardGenerator(habit=...)``)."""
    return variant_task(f"habit{round(100 * habit)}", f"combinations by a habit of {habit}", habit=habit)


def e5(ds, obs, act, habits, seeds, steps, episodes, data_episodes) -> None:
    """BC on data generated with the habit (the first ``data_episodes`` episodes), next to BC on as many
    episodes of the dataset."""
    from d5rl.datasets.loading import load_dataset

    n = data_episodes or 160
    print(f"\nE5: BC {steps} steps on the first {n} episodes of data generated with the habit; {episodes} episodes")
    print(
        "| data | episodes of the commonest order | score per seed | mean | subtasks done (mw / kettle / bb / tb / light / slide / hinge) |"
    )
    print("|---|---:|---|---:|---|")
    sources = [("dataset (round-robin)", None)] + [(f"habit {p}", p) for p in habits]
    for what, habit in sources:
        if habit is None:
            rows = np.flatnonzero(ds.transition_episode < n)
            x, y, meta = obs[rows], act[rows], ds.episode_meta[:n]
        else:
            hd = load_dataset(habit_task(habit), episodes=n, workers=1, progress=False)
            x, y, meta = np.asarray(hd.observations, np.float32), np.asarray(hd.arrays["actions"]), hd.episode_meta
        orders = [tuple(m["subtasks"]) for m in meta]
        common = max(orders.count(o) for o in set(orders))
        cols = bc_columns(x, y, seeds, steps, episodes)
        print(f"| {what} | {common} | {cols} |", flush=True)


def e6(slips, seeds, steps, episodes, data_episodes) -> None:
    """BC on data whose demonstrator slips off course and corrects (``Demonstrator(slips=p)``), the first
    ``data_episodes`` episodes; E5's first row is the dataset's own at the same size."""
    from d5rl.datasets.loading import load_dataset

    n = data_episodes or 160
    print(f"\nE6: BC {steps} steps on the first {n} episodes of data with slips; {episodes} episodes")
    print(
        "| slips per step | slip steps | objects per episode | score per seed | mean | subtasks done (mw / kettle / bb / tb / light / slide / hinge) |"
    )
    print("|---|---:|---:|---|---:|---|")
    for p in slips:
        task = variant_task(f"slips{round(1000 * p)}", f"slips with probability {p} per step", slips=p)
        hd = load_dataset(task, episodes=n, workers=1, progress=False)
        x, y = np.asarray(hd.observations, np.float32), np.asarray(hd.arrays["actions"], np.float32)
        solved = np.mean([m["num_solved"] for m in hd.episode_meta])
        # slip steps: the arm's action held constant over consecutive steps outside the controller's law
        held = np.all(np.abs(np.diff(y[:, :7], axis=0)) < 1e-7, axis=1).mean()
        cols = bc_columns(x, y, seeds, steps, episodes)
        print(
            f"| {p} | {held:.1%} | {solved:.2f} | {cols} |",
            flush=True,
        )


def e7(noise_scales, seeds, steps, episodes, data_episodes) -> None:
    """BC on one order of subtasks (an operator with habit 1: microwave, kettle, bottom burner, top burner)
    with the demonstrator's action noise scaled: does a wider spread of states teach BC to chain subtasks?"""
    from d5rl.datasets.loading import load_dataset

    n = data_episodes or 160
    print(f"\nE7: BC {steps} steps on the first {n} episodes of one order, action noise scaled; {episodes} episodes")
    print(
        "| noise scale | action noise std | objects per episode | score per seed | mean | subtasks done (mw / kettle / bb / tb / light / slide / hinge) |"
    )
    print("|---|---:|---:|---|---:|---|")
    for scale in noise_scales:
        kwargs = {"habit": 1.0} if scale == 1.0 else {"habit": 1.0, "noise_scale": scale}
        tag = "habit100" if scale == 1.0 else f"habit100-noise{round(10 * scale)}"
        task = variant_task(tag, f"one order, action noise x{scale}", **kwargs)
        hd = load_dataset(task, episodes=n, workers=1, progress=False)
        x, y = np.asarray(hd.observations, np.float32), np.asarray(hd.arrays["actions"], np.float32)
        solved = np.mean([m["num_solved"] for m in hd.episode_meta])
        noise = np.mean([m["style"]["noise"] for m in hd.episode_meta])
        cols = bc_columns(x, y, seeds, steps, episodes)
        print(
            f"| {scale} | {noise:.3f} | {solved:.2f} | {cols} |",
            flush=True,
        )


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--only",
        choices=("e1", "e2", "e3", "e4", "e5", "e6", "e7"),
        action="append",
        help="run only these (repeatable)",
    )
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--steps", type=int, default=10_000, help="BC gradient steps (the state Table 1 budget)")
    ap.add_argument("--episodes", type=int, default=20, help="evaluation episodes per policy")
    ap.add_argument("--data-episodes", type=int, default=None, help="use the dataset's first N (E5: default 160)")
    ap.add_argument("--habit", type=float, nargs="+", default=[0.8, 0.9], help="E4: the habit's probabilities")
    ap.add_argument("--slips", type=float, nargs="+", default=[0.03], help="E6: slips per step")
    ap.add_argument("--noise-scale", type=float, nargs="+", default=[1.0, 4.0], help="E7: action noise scales")
    ap.add_argument("--k", type=int, nargs="+", default=[1], help="E2: neighbours averaged per action")
    args = ap.parse_args(argv)
    which = args.only or ["e1", "e2", "e3", "e4", "e5", "e6", "e7"]
    t0 = time.time()
    ds, obs, act = load(None if set(which) <= {"e5", "e6", "e7"} else args.data_episodes)
    print(
        f"{ds.metadata['dataset']} v{ds.metadata['dataset_version']} ({ds.metadata['generator_version']}): "
        f"{len(ds.episode_lengths)} episodes, {len(act):,} transitions"
    )
    if "e1" in which:
        e1(ds, obs, act, args.seeds, args.steps, args.episodes)
    if "e2" in which:
        e2(ds, obs, act, args.k, args.episodes)
    if "e3" in which:
        e3(ds, obs, act, args.seeds, args.steps)
    if "e4" in which:
        e4(ds, obs, act, args.habit, args.seeds, args.steps, args.episodes)
    if "e5" in which:
        e5(ds, obs, act, args.habit[-1:], args.seeds, args.steps, args.episodes, args.data_episodes)
    if "e6" in which:
        e6(args.slips, args.seeds, args.steps, args.episodes, args.data_episodes)
    if "e7" in which:
        e7(args.noise_scale, args.seeds, args.steps, args.episodes, args.data_episodes)
    print(f"\n({time.time() - t0:.0f} s)")


if __name__ == "__main__":
    main()
