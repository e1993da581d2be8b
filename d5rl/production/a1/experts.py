"""Train the A1 agents: the data-collecting agents and the score-reference experts.

    python -m d5rl.production.a1.experts train --agents speed-0.5 speed-1.0 --steps 203750 --snapshot-every 20000 \
        --first-segment 1250
    python -m d5rl.production.a1.experts train --agents heading --steps 145000 --snapshot-every 20000
    python -m d5rl.production.a1.experts train --agents hiking --init-from heading --steps 65000 --snapshot-every 20000
    python -m d5rl.production.a1.experts check --policy-dir experiments/a1-agents/policies   # the speed bar
    python -m d5rl.production.a1.experts publish               # ship them to d5rl/envs/a1/policies
    python -m d5rl.production.a1.experts export                # between machines (see below)

The agents of the ``a1-*-v1`` tasks (:mod:`d5rl.envs.a1.v1`, the release's action range and reward) end
in ``-v1`` and train the same way::

    T="python -m d5rl.production.a1.experts train --snapshot-every 20000 --first-segment 1250 --single-thread"
    $T --agents speed-0.5-v1 speed-0.8-v1 speed-1.0-v1 --steps 300000
    $T --agents goals-mixed-v1 goals-smooth-v1 --steps 300000
    $T --agents run-1.25-v1 --steps 143750
    $T --agents hiking-v1 --init-from goals-mixed-v1 --steps 100000

(the commands as run, one process per core: ``docs/datacards/a1.md``).

Every agent is SAC with a pair of LayerNorm critics at an update-to-data ratio of 2 (our
``rlpd`` learner without offline data).  Agents with the same observation size train in one
process: their learners are stacked and one vmapped, jitted call per environment step updates
all of them and samples their next actions, while their environments step on the host.

Along training each agent's actor is saved at every snapshot boundary
(``policies/<agent>/snapshot-XX.npz``) and ``policies/<agent>/log.json`` records, per
snapshot, the episodes and steps it collected.  Segments start short (``--first-segment``) and
double up to ``--snapshot-every``: the policy changes fastest early on, and a segment's steps are
replayed by the snapshot at its start.  The dataset generator replays these snapshots
for the same number of episodes, which reproduces the agent's replay buffer from first
exploration to expert without re-running RL on every user's machine.  Reference agents
(``role="reference"``) only define a score reference: only their final policy ships.

**Resuming.** At every snapshot boundary all environments are reset (a running episode ends
there as a time-out) and a checkpoint is written to ``--work-dir`` (learners, replay buffers,
logs, RNG states; :mod:`d5rl.training.checkpoint`).  Running the same command again continues
from it; ``--max-minutes`` stops at the first boundary after the budget.

**Across machines** (training can outlast a machine you hold for a few hours): ``export``
writes the checkpoints without their replay buffers to ``experiments/a1-agents`` for committing,
and ``train`` resumes from there when ``--work-dir`` has none (:mod:`d5rl.production.a1.resume`).

**Training reward.** The tasks' rewards are flat within ±0.1 m/s of the target, and their energy
term then pulls an agent to the slow edge (agents trained on the task reward settle at 0.48 / 0.71 /
0.70 m/s for targets 0.5 / 0.8 / 1.0).  Data agents therefore train on the same reward with the flat band
narrowed to ``[target, target + 0.03]`` (:attr:`AgentSpec.band`), so that each tracks its
target; datasets store the reward terms and relabel every step for the task at load time.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from d5rl.envs.a1.published import POLICY_DIR
from d5rl.parallel import configure_worker
from d5rl.production.a1.agents import AGENTS, make_env, training_reward
from d5rl.production.a1.policy import save_actor
from d5rl.production.a1.resume import SAVED_DIR, WORK_DIR, export, publish, record, refill_buffer
from d5rl.production.a1.speedcheck import main as check
from d5rl.training.checkpoint import Checkpoint, load_checkpoint, save_checkpoint


def boundaries(start_steps: int, first_segment: int, snapshot_every: int, steps: int) -> frozenset[int]:
    """Snapshot boundaries: learning starts at ``start_steps``; the first learning segment is
    ``first_segment`` steps and each next one twice the last, up to ``snapshot_every`` (the policy
    changes fastest early, and each segment's data is replayed by the snapshot that starts it)."""
    out, t, length = set(), start_steps, first_segment
    while t <= steps:
        out.add(t)
        t, length = t + length, min(2 * length, snapshot_every)
    return frozenset(out)


def learner_config(utd: int):
    from d5rl.agents import rlpd  # optional dependency: JAX (the `train` extra); publish/export/check run without

    return rlpd.get_config().replace(num_qs=2, num_min_qs=2, utd_ratio=utd, batch_size=256, hidden_dims=(256, 256))


@dataclasses.dataclass
class Segment:
    """Training steps between two snapshot boundaries, acted by one snapshot (None: random actions)."""

    snapshot: str | None
    start_step: int
    episodes: int = 0
    steps: int = 0
    returns: list = dataclasses.field(default_factory=list)  # per finished episode, training reward
    speeds: list = dataclasses.field(default_factory=list)  # per finished episode, mean forward speed
    falls: int = 0

    def summary(self) -> dict:
        return {
            "snapshot": self.snapshot,
            "start_step": self.start_step,
            "episodes": self.episodes,
            "steps": self.steps,
            "falls": self.falls,
            "mean_return": float(np.mean(self.returns)) if self.returns else None,
            "mean_speed": float(np.mean(self.speeds)) if self.speeds else None,
        }


class Trainer:
    """Several agents of one observation size, trained together; see the module docstring."""

    def __init__(
        self,
        agents: list[str],
        steps: int,
        seed: int,
        snapshot_every: int,
        start_steps: int,
        utd: int,
        work_dir: Path,
        policy_dir: Path = SAVED_DIR / "policies",
        init_from: str | None = None,
        saved_root: Path | None = None,
        first_segment: int | None = None,
    ):
        import jax

        dims = {AGENTS[a].obs_dim for a in agents}
        if len(dims) != 1:
            raise ValueError(f"agents {agents} have different observation sizes {dims}: train them separately")
        self.names, self.specs = list(agents), [AGENTS[a] for a in agents]
        self.steps, self.seed, self.utd = int(steps), int(seed), int(utd)
        self.snapshot_every, self.start_steps = int(snapshot_every), int(start_steps)
        self.first_segment = int(first_segment or snapshot_every)
        self.boundaries = boundaries(self.start_steps, self.first_segment, self.snapshot_every, self.steps)
        self.work_dir, self.policy_dir, self.init_from = Path(work_dir), Path(policy_dir), init_from
        self.saved_root = None if saved_root is None else Path(saved_root)  # exported checkpoints (no buffers)
        self.config = learner_config(utd)
        self.prior_seconds = 0.0  # training time of earlier processes (set by a resume)
        self.envs = [make_env(a) for a in agents]
        self.obs_dim = dims.pop()
        self.k = len(agents)
        n = self.steps
        self.buf = {
            "observations": np.zeros((self.k, n, self.obs_dim), np.float32),
            "next_observations": np.zeros((self.k, n, self.obs_dim), np.float32),
            "actions": np.zeros((self.k, n, 12), np.float32),
            "rewards": np.zeros((self.k, n), np.float32),
            "masks": np.zeros((self.k, n), np.float32),
        }
        self._step_fn = jax.jit(self._fused_step, donate_argnums=0)

    # --- learners -----------------------------------------------------------------------------------
    def _new_learners(self):
        import jax  # optional dependency (the `train` extra), as every JAX import here
        import jax.numpy as jnp

        from d5rl.agents.rlpd import RLPDAgent  # optional dependency: JAX

        obs = np.zeros((1, self.obs_dim), np.float32)
        learners = [
            RLPDAgent.create(self.seed * 1000 + i, obs, np.zeros((1, 12), np.float32), self.config)
            for i in range(self.k)
        ]
        if self.init_from is not None:
            data = self._learner_file(self.init_from).read_bytes()
            learners = [learners[i].from_bytes(data) for i in range(self.k)]
        treedef = jax.tree_util.tree_structure(learners[0])
        leaves = [jax.tree_util.tree_leaves(a) for a in learners]
        return treedef.unflatten([jnp.stack(x) for x in zip(*leaves)])

    def _unstacked(self, learners, i: int):
        import jax

        return jax.tree_util.tree_map(lambda x: x[i], learners)

    @staticmethod
    def _fused_step(learners, batch, obs, key):
        """Update every learner on its batch, then sample its next action (one host round trip)."""
        import jax

        def one(agent, b, o, k):
            agent, info = agent._update(b)
            dist = agent.actor.apply_fn({"params": agent.actor.params}, o[None])
            return agent, info, jax.numpy.clip(dist.sample(k)[0], -1, 1)

        keys = jax.random.split(key, obs.shape[0])
        return jax.vmap(one)(learners, batch, obs, keys)

    @staticmethod
    def _act(learners, obs, key):
        import jax

        def one(agent, o, k):
            return jax.numpy.clip(agent.actor.apply_fn({"params": agent.actor.params}, o[None]).sample(k)[0], -1, 1)

        return jax.vmap(one)(learners, obs, jax.random.split(key, obs.shape[0]))

    # --- checkpoints ---------------------------------------------------------------------------------
    def _save(self, learners, t: int, rng, key, segments, seconds: float) -> None:
        import flax

        state = {
            "agents": self.names,
            "t": t,
            "steps": self.steps,
            "seed": self.seed,
            "utd": self.utd,
            "snapshot_every": self.snapshot_every,
            "first_segment": self.first_segment,
            "start_steps": self.start_steps,
            "rng": rng.bit_generator.state,
            "key": np.asarray(key).tolist(),
            "train_seconds": round(seconds),
            "segments": [[dataclasses.asdict(s) for s in segs] for segs in segments],
        }
        buffer = {k: v[:, :t] for k, v in self.buf.items()}
        self.work_dir.mkdir(parents=True, exist_ok=True)
        save_checkpoint(self.work_dir, Checkpoint(flax.serialization.to_bytes(learners), state, buffer))

    def _load(self, learners):
        import flax

        ckpt = load_checkpoint(self.work_dir)
        if ckpt is None and self.saved_root is not None:
            ckpt = load_checkpoint(self.saved_root / "checkpoints" / "+".join(self.names))
        if ckpt is None:
            return None
        s = {"first_segment": ckpt.state["snapshot_every"], **ckpt.state}  # (uniform segments before it was stored)
        mine = {
            "agents": self.names,
            "seed": self.seed,
            "utd": self.utd,
            "snapshot_every": self.snapshot_every,
            "first_segment": self.first_segment,
            "start_steps": self.start_steps,
        }
        if {k: s[k] for k in mine} != mine:
            raise ValueError(
                f"{ckpt.path} holds another training run ({ {k: s[k] for k in mine} }); "
                "pass another --work-dir / --saved-dir or delete it"
            )
        t = int(s["t"])
        segments = [[Segment(**d) for d in segs] for segs in s["segments"]]
        if ckpt.buffer:
            for k, v in ckpt.buffer.items():
                self.buf[k][:, :t] = v
        else:
            print(
                f"[{'+'.join(self.names)}] {ckpt.path} has no replay buffer: refilling {t} steps per agent "
                "by replaying the snapshots",
                flush=True,
            )
            refill_buffer(self.buf, t, segments, self.names, self.envs, self.policy_dir, self.seed)
        # training time of the earlier processes (checkpoints from before it was stored: the agents' logs)
        logs = [self.policy_dir / n / "log.json" for n in self.names]
        earlier = [json.loads(f.read_text()).get("train_seconds", 0) for f in logs if f.exists()]
        self.prior_seconds = s.get("train_seconds", max(earlier, default=0))
        rng = np.random.default_rng()
        rng.bit_generator.state = s["rng"]
        return flax.serialization.from_bytes(learners, ckpt.agent), t, rng, np.asarray(s["key"], np.uint32), segments

    def _learner_file(self, agent: str) -> Path:
        """A finished agent's learner: this machine's, else the exported one."""
        local = self.work_dir.parent / "learners" / f"{agent}.msgpack"
        if local.exists() or self.saved_root is None:
            return local
        return self.saved_root / "learners" / f"{agent}.msgpack"

    # --- outputs -------------------------------------------------------------------------------------
    def _write_logs(self, segments, t: int, seconds: float) -> None:
        for name, spec, segs in zip(self.names, self.specs, segments):
            log = {
                "agent": name,
                **{k: v for k, v in dataclasses.asdict(spec).items()},
                "seed": self.seed,
                "steps": t,
                "utd": self.utd,
                "start_steps": self.start_steps,
                "snapshot_every": self.snapshot_every,
                "first_segment": self.first_segment,
                "train_seconds": round(seconds),
                "trained_with": self.names,
                "config": self.config.to_dict(),
                "segments": [s.summary() for s in segs],
            }
            out = self.policy_dir / name
            out.mkdir(parents=True, exist_ok=True)
            (out / "log.json").write_text(json.dumps(log, indent=1, default=str) + "\n")

    def _snapshot(self, learners, i: int, filename: str) -> None:

        save_actor(self._unstacked(learners, i).actor.params, self.policy_dir / self.names[i] / filename)

    def _clear_outputs(self) -> None:
        for name in self.names:
            for old in (self.policy_dir / name).glob("*.npz"):
                old.unlink()

    # --- the loop ------------------------------------------------------------------------------------
    def run(self, max_minutes: float | None = None, log_every: int = 5000) -> bool:
        """Train to ``steps`` (or to the first boundary after ``max_minutes``); True when finished."""
        import jax

        learners = self._new_learners()
        loaded = self._load(learners)
        if loaded is None:
            self._clear_outputs()
            t, rng, key = 0, np.random.default_rng(self.seed), jax.random.PRNGKey(self.seed)
            segments = [[Segment(None, 0)] for _ in self.names]
        else:
            learners, t, rng, key, segments = loaded
            print(f"[{'+'.join(self.names)}] resuming at step {t}", flush=True)
        t0 = time.time()
        obs = self._reset_all(rng)
        ep = [dict(ret=0.0, speeds=[], len=0) for _ in self.names]
        key = jax.numpy.asarray(key, dtype=jax.numpy.uint32)
        actions = None
        while t < self.steps:
            if self._is_boundary(t) and segments[0][-1].start_step != t:  # (not the one a resume starts at)
                learners, obs, ep, actions, key = self._boundary(learners, t, rng, key, segments, t0)
                if max_minutes is not None and time.time() - t0 > 60 * max_minutes:
                    print(
                        f"[{'+'.join(self.names)}] stopping at step {t} after {max_minutes} min; "
                        "run the same command to continue",
                        flush=True,
                    )
                    return False
            if t < self.start_steps or actions is None:
                if t < self.start_steps:
                    actions = rng.uniform(-1, 1, (self.k, 12)).astype(np.float32)
                else:
                    key, sub = jax.random.split(key)
                    actions = np.asarray(self._act(learners, obs, sub))
            nxt = np.empty_like(obs)
            for i, (env, spec) in enumerate(zip(self.envs, self.specs)):
                o2, _, term, _, info = env.step(actions[i])
                r = training_reward(spec, info)
                record(self.buf, i, t, obs[i], actions[i], r, o2, term)
                e = ep[i]
                e["ret"] += r
                e["speeds"].append(info["forward_speed"])
                e["len"] += 1
                segments[i][-1].steps += 1
                if term or e["len"] >= spec.episode_steps:
                    self._end_episode(segments[i][-1], e, fell=term)
                    o2, _ = env.reset(seed=int(rng.integers(2**31)))
                    ep[i] = dict(ret=0.0, speeds=[], len=0)
                nxt[i] = o2
            obs = nxt
            t += 1
            if t > self.start_steps:
                idx = rng.integers(0, t, (self.k, self.utd * 256))
                batch = {
                    k: np.take_along_axis(v, idx.reshape(idx.shape + (1,) * (v.ndim - 2)), axis=1)
                    for k, v in self.buf.items()
                }
                key, sub = jax.random.split(key)
                learners, _, actions = self._step_fn(learners, batch, obs, sub)
                actions = np.asarray(actions)
            else:
                actions = None
            if t % log_every == 0:
                self._print(t, segments, t0)
        learners, *_ = self._boundary(learners, t, rng, key, segments, t0, final=True)
        return True

    def _is_boundary(self, t: int) -> bool:
        return t in self.boundaries

    def _reset_all(self, rng):
        return np.stack([env.reset(seed=int(rng.integers(2**31)))[0] for env in self.envs]).astype(np.float32)

    @staticmethod
    def _end_episode(seg: Segment, e: dict, fell: bool) -> None:
        seg.episodes += 1
        seg.returns.append(float(e["ret"]))
        seg.speeds.append(float(np.mean(e["speeds"])))
        seg.falls += int(fell)

    def _boundary(self, learners, t, rng, key, segments, t0, final: bool = False):
        """Snapshot, close the segment, checkpoint, reset every environment."""
        import flax

        for i in range(len(self.specs)):
            if final:
                self._snapshot(learners, i, "final.npz")
            else:  # reference agents' snapshots too: a resume rebuilds the replay buffer from them
                name = f"snapshot-{len(segments[i]):02d}.npz"
                self._snapshot(learners, i, name)
                segments[i].append(Segment(name, t))
        seconds = self.prior_seconds + time.time() - t0  # over every process that trained them
        self._write_logs(segments, t, seconds)
        self._save(learners, t, rng, key, segments, seconds)
        if final:
            out = self.work_dir.parent / "learners"
            out.mkdir(parents=True, exist_ok=True)
            for i, name in enumerate(self.names):
                (out / f"{name}.msgpack").write_bytes(flax.serialization.to_bytes(self._unstacked(learners, i)))
        obs = self._reset_all(rng)
        return learners, obs, [dict(ret=0.0, speeds=[], len=0) for _ in self.names], None, key

    def _print(self, t, segments, t0) -> None:
        parts = []
        for name, segs in zip(self.names, segments):
            done = [s for s in segs if s.returns][-1:] or segs[-1:]
            s = done[-1]
            r = f"{np.mean(s.returns[-5:]):.0f}" if s.returns else "-"
            v = f"{np.mean(s.speeds[-5:]):.2f}" if s.speeds else "-"
            parts.append(f"{name}: R {r} v {v} falls {s.falls}")
        print(f"[{t}/{self.steps} {time.time() - t0:.0f}s] " + " | ".join(parts), flush=True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    q = sub.add_parser("train", help="train agents of one observation size together (resumable)")
    q.add_argument("--agents", nargs="+", choices=sorted(AGENTS), required=True)
    q.add_argument("--steps", type=int, default=150_000, help="environment steps per agent")
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--snapshot-every", type=int, default=15_000, help="the longest segment between snapshots")
    q.add_argument(
        "--first-segment",
        type=int,
        help="steps of the first learning segment; each next one doubles up to --snapshot-every "
        "(default: --snapshot-every, uniform segments)",
    )
    q.add_argument("--start-steps", type=int, default=5_000, help="uniform random steps before learning")
    q.add_argument("--utd", type=int, default=2)
    q.add_argument("--init-from", choices=sorted(AGENTS), help="start from this agent's final learner")
    q.add_argument("--work-dir", type=Path, help=f"checkpoints (default {WORK_DIR}/<agents>)")
    q.add_argument(
        "--policy-dir",
        type=Path,
        default=SAVED_DIR / "policies",
        help=f"snapshots and logs (default %(default)s; published to {POLICY_DIR} when trained)",
    )
    q.add_argument(
        "--saved-dir",
        type=Path,
        default=SAVED_DIR,
        help="exported checkpoints to resume from when --work-dir has none (default %(default)s)",
    )
    q.add_argument("--max-minutes", type=float, help="stop at the first snapshot boundary after this long")
    q.add_argument("--log-every", type=int, default=5000)
    q.add_argument(
        "--single-thread",
        action="store_true",
        help="one compute thread (faster when several trainings share the cores)",
    )
    e = sub.add_parser("export", help="copy the latest checkpoints (without replay buffers) for committing")
    e.add_argument("--work-root", type=Path, default=WORK_DIR)
    e.add_argument("--saved-dir", type=Path, default=SAVED_DIR)
    c = sub.add_parser("check", help="mean forward speed and falls of each agent's final policy")
    c.add_argument(
        "--agents", nargs="+", choices=sorted(AGENTS), help="default: every agent with a final policy in --policy-dir"
    )
    c.add_argument("--episodes", type=int, default=10)
    c.add_argument("--seed", type=int, default=0)
    c.add_argument(
        "--policy-dir",
        type=Path,
        default=POLICY_DIR,
        help=f"whose final policies (default: the shipped ones; {SAVED_DIR / 'policies'}: the trained ones)",
    )
    p = sub.add_parser("publish", help=f"ship finished agents' policies to {POLICY_DIR} (the datasets replay them)")
    p.add_argument(
        "--agents", nargs="+", choices=sorted(AGENTS), help="default: every agent with a final policy in --policy-dir"
    )
    p.add_argument("--policy-dir", type=Path, default=SAVED_DIR / "policies")
    args = ap.parse_args(argv)
    if args.cmd == "train":
        if args.single_thread:
            configure_worker(single_thread=True)
        work = args.work_dir or WORK_DIR / "+".join(args.agents)
        Trainer(
            args.agents,
            args.steps,
            args.seed,
            args.snapshot_every,
            args.start_steps,
            args.utd,
            work,
            args.policy_dir,
            args.init_from,
            args.saved_dir,
            args.first_segment,
        ).run(args.max_minutes, args.log_every)
    elif args.cmd == "export":
        export(args.work_root, args.saved_dir)
    elif args.cmd == "publish":
        publish(
            args.agents or [a for a in sorted(AGENTS) if (args.policy_dir / a / "final.npz").exists()], args.policy_dir
        )
    else:
        agents = args.agents or [a for a in sorted(AGENTS) if (args.policy_dir / a / "final.npz").exists()]
        check(agents, args.episodes, args.seed, args.policy_dir)


if __name__ == "__main__":
    main()
