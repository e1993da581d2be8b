"""``d5rl train`` and ``d5rl eval`` (wired into :mod:`d5rl.cli` by ``add_*_parser``)."""

from __future__ import annotations

import argparse
import json
import sys

from d5rl import settings
from d5rl.agents import AGENTS
from d5rl.agents.config import ConfigError
from d5rl.errors import D5RLError
from d5rl.registry import get_spec, make_env
from d5rl.settings import run_steps
from d5rl.training.config import check_run, final_eval_episodes


def add_train_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "train",
        help="train a reference agent offline (and optionally fine-tune online)",
        description="Train ALGO on TASK. Runs resume from their checkpoint when started again with the same "
        "--run-dir. Config keys (agent and loop) are set with --set key=value; "
        "see `d5rl train ALGO TASK --show-config`.",
    )
    p.add_argument("algo", choices=sorted(AGENTS), help="agent")
    p.add_argument("task", help="task id (`d5rl list`)")
    p.add_argument(
        "--offline-steps",
        type=int,
        default=None,
        help="gradient updates on the dataset (default 500000; none for RLPD when fine-tuning online)",
    )
    p.add_argument("--online-steps", type=int, default=0, help="environment steps of online fine-tuning")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config value (repeatable)",
    )
    p.add_argument("--run-dir", default=None, help="default: runs/TASK/ALGO/seedS")
    p.add_argument(
        "--show-config",
        action="store_true",
        help="print the config this run would use (d5rl/configs/settings.json under --set) and exit",
    )
    p.set_defaults(func=cmd_train)
    return p


def cmd_train(args) -> int:
    offline, online = run_steps(args.algo, args.offline_steps, args.online_steps)
    if args.offline_steps and offline != args.offline_steps:
        print(
            f"note: {args.algo} has no offline phase before fine-tuning (its online batches mix in the offline "
            f"data); training {online} online steps only",
            file=sys.stderr,
        )
    check_run(offline, online, args.seed)
    spec = settings.resolve(
        args.algo, args.task, args.overrides, offline_steps=offline, online_steps=online, seed=args.seed
    )
    if args.show_config:
        print(json.dumps(spec.to_json(), indent=2))
        return 0
    from d5rl.training.loop import train  # JAX: --show-config and `d5rl --help` start without it

    res = train(spec, args.run_dir)
    res.pop("agent", None)
    print(json.dumps(res, indent=2))
    return 0


def add_eval_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("eval", help="evaluate a trained agent from its run directory")
    p.add_argument("run_dir", help="directory written by `d5rl train`")
    p.add_argument(
        "--episodes", type=int, default=None, help="how many episodes (default: as many as the run's final evaluation)"
    )
    p.add_argument(
        "--envs", type=int, default=None, help="environments stepped in lockstep (default: the run's eval_envs)"
    )
    p.add_argument("--processes", action="store_true", help="one process per environment")
    p.add_argument(
        "--seed",
        type=int,
        default=None,
        help="episode i resets with seed + i (default: the run's evaluation seed, 10000 × (run seed + 1))",
    )
    p.add_argument(
        "--video", default=None, metavar="PATH", help="record the first episode (.mp4, .mkv, .mov, .avi or .gif)"
    )
    p.add_argument("--task", default=None, help="evaluate on another task id (same spaces)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=cmd_eval)
    return p


def cmd_eval(args) -> int:
    from d5rl.training.evaluation import evaluate  # JAX (the train extra): loaded by the commands that need it
    from d5rl.training.loop import load_run  # JAX (the train extra): loaded by the commands that need it
    from d5rl.training.parts import evaluation_seed
    from d5rl.training.rundir import RunDir

    for name, v in (("--episodes", args.episodes), ("--envs", args.envs)):
        if v is not None and v < 1:
            raise ConfigError(f"{name} must be at least 1, got {v}", f"pass e.g. {name} 10")
    agent, resolved = load_run(args.run_dir)
    task = args.task or resolved["task_id"]
    if task != resolved["task_id"]:
        _check_same_spaces(resolved["task_id"], task)
    train = resolved["train"]
    # the defaults are the run's final evaluation: on the run's own task they reproduce its summary.json
    episodes = args.episodes or final_eval_episodes(train)
    seed = evaluation_seed(resolved["seed"]) if args.seed is None else args.seed
    res = evaluate(
        agent,
        task,
        episodes,
        seed,
        num_envs=args.envs or train["eval_envs"],
        frame_stack=train["frame_stack"],
        processes=args.processes,
        video_path=args.video,
    )
    if (args.episodes, args.envs, args.seed, args.task) == (None,) * 4:  # the run's own final evaluation
        _compare_with_final(res, RunDir(args.run_dir).read_summary())
    for per_episode in ("returns", "lengths", "scores"):
        res.pop(per_episode, None)
    if args.json:
        print(json.dumps({"task_id": task, **res}, indent=2))
        return 0
    print(
        f"{task}: {res['episodes']} episodes, return {res['return']:.2f} ± {res['return_std']:.2f}, "
        f"length {res['length']:.1f}, success {res['success']:.2f}"
        + (f", video {res['video']}" if "video" in res else "")
    )
    for k, v in res.get("stats", {}).items():
        print(f"  {k}: {v:.2f}")
    if "final_evaluation_score" in res:
        differ = res.get("episodes_not_the_same")
        same = "the same" if res["final_evaluation_score"] == res["score"] and not differ else "not the same"
        if differ:
            same += f" (episode{'s' if len(differ) > 1 else ''} {', '.join(map(str, differ))} scored otherwise)"
        print(f"the run's final evaluation (summary.json) scored {res['final_evaluation_score']:.3f}: {same}")
    if "score" in res:
        print(f"normalized score: {res['score']:.3f} ± {res['score_std']:.3f}")
    else:
        print(f"mean return: {res['return']:.2f} (this task has no score reference)")
    return 0


def _compare_with_final(res: dict, final: dict | None) -> None:
    """Add to an evaluation's result what the run's final evaluation (its ``summary.json``) scored, and which
    episodes scored otherwise (runs that recorded each episode's score)."""
    if final is None or "score" not in res or not isinstance(final.get("score"), float):
        return
    res["final_evaluation_score"] = final["score"]
    was = final.get("scores")
    if isinstance(was, list) and len(was) == len(res["scores"]):
        res["episodes_not_the_same"] = [i + 1 for i, (a, b) in enumerate(zip(was, res["scores"])) if a != b]


def _check_same_spaces(trained_on: str, task: str) -> None:
    """An agent runs on another task only if that task has the same observation and action spaces."""
    spaces = {}
    for tid in (trained_on, task):
        env = make_env(get_spec(tid).id)
        spaces[tid] = (env.observation_space, env.action_space)
        env.close()
    for i, what in enumerate(("observation", "action")):
        a, b = spaces[trained_on][i], spaces[task][i]
        if a != b:
            raise D5RLError(
                f"the agent was trained on {trained_on}, whose {what} space {a} differs from {task}'s {b}",
                "pass a --task whose spaces match (`d5rl info TASK` prints them)",
            )
