"""How fast can the A1 of ``a1-run-v0`` move within v0's action range?  A cross-entropy search over open-loop periodic gaits.

    python experiments/a1-gait-search/search.py [--iters 30] [--pop 48] [--seed 0] [--out result.json]

The SAC data agents plateau at ~0.82 m/s on the run task (target 1.25 m/s; A1 data card).  This asks the
environment, not a learner: each candidate is a periodic gait (one frequency; per-leg phase; thigh and calf
sinusoids with amplitudes, offsets and a thigh-calf lag; hip offsets), played open loop for 5 s from the
task's reset, scored by its mean forward speed over the last 3 s (a fall scores -1).  The task's own
environment runs it: 20 Hz PD position control, kp 60, kd 6, action scale [0.2, 0.4, 0.4] around the
nominal pose.  If the best gait found runs well above 1.25 m/s, the actuation allows the target and the
plateau is the learner's; if not, that is evidence the target is at the edge of what the task allows.
"""

from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import numpy as np

import d5rl  # noqa: F401  (registers the d5rl/ task ids with Gymnasium)

# name, low, high
PARAMS = [
    ("freq_hz", 1.0, 10.0),  # up to the 20 Hz control's Nyquist frequency
    ("thigh_amp", 0.0, 3.0), ("calf_amp", 0.0, 3.0),  # action units, clipped to [-1, 1] after the sum: large = square wave
    ("thigh_off", -0.8, 0.8), ("calf_off", -0.8, 0.8), ("calf_lag", -np.pi, np.pi),
    ("phase_FL", 0.0, 2 * np.pi), ("phase_RR", 0.0, 2 * np.pi), ("phase_RL", 0.0, 2 * np.pi),
    ("hip_front", -0.5, 0.5), ("hip_rear", -0.5, 0.5),
    ("rear_scale", 0.5, 1.5),  # rear legs' amplitude relative to the front legs'
]
LOW = np.array([p[1] for p in PARAMS])
HIGH = np.array([p[2] for p in PARAMS])
STEPS, SCORED = 100, 60  # control steps played (5 s) and scored (the last 3 s)


def actions(theta: np.ndarray, steps: int = STEPS, dt: float = 0.05) -> np.ndarray:
    p = dict(zip([q[0] for q in PARAMS], theta))
    t = np.arange(steps) * dt
    out = np.zeros((steps, 12))
    phases = [0.0, p["phase_FL"], p["phase_RR"], p["phase_RL"]]  # legs FR, FL, RR, RL
    for leg, ph in enumerate(phases):
        rear = leg >= 2
        scale = p["rear_scale"] if rear else 1.0
        w = 2 * np.pi * p["freq_hz"] * t + ph
        side = 1.0 if leg % 2 == 0 else -1.0  # right legs +, left legs -: hips splay symmetrically
        out[:, 3 * leg] = side * (p["hip_rear"] if rear else p["hip_front"])
        out[:, 3 * leg + 1] = p["thigh_off"] + scale * p["thigh_amp"] * np.sin(w)
        out[:, 3 * leg + 2] = p["calf_off"] + scale * p["calf_amp"] * np.sin(w + p["calf_lag"])
    return np.clip(out, -1.0, 1.0).astype(np.float32)


def evaluate(env, theta: np.ndarray, seed: int) -> tuple[float, bool]:
    """(mean forward speed over the last SCORED steps, or -1 after a fall; whether it fell)."""
    env.reset(seed=seed)
    speeds = []
    for a in actions(theta):
        _, _, term, _, info = env.step(a)
        speeds.append(info["forward_speed"])
        if term:
            return -1.0, True
    return float(np.mean(speeds[-SCORED:])), False


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iters", type=int, default=30)
    ap.add_argument("--pop", type=int, default=48)
    ap.add_argument("--elite", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None)
    ap.add_argument("--action-range", type=float, default=1.0,
                    help="counterfactual, not the task: multiply the joint-target range around the nominal pose")
    ap.add_argument("--kp", type=float, default=None, help="counterfactual, not the task: PD stiffness (task: 60)")
    args = ap.parse_args(argv)
    env = gym.make("d5rl/a1-run-v0").unwrapped  # the task's environment without the time limit
    if args.action_range != 1.0:
        from d5rl.envs.a1 import task

        task.ACTION_SCALE = task.ACTION_SCALE * args.action_range  # read by A1Env.step
    if args.kp is not None:  # position actuators: force = kp * (target - q) - kd * qdot
        env.model.actuator_gainprm[:, 0] = args.kp
        env.model.actuator_biasprm[:, 1] = -args.kp
    rng = np.random.default_rng(args.seed)
    mean, std = (LOW + HIGH) / 2, (HIGH - LOW) / 2
    best, best_v, history, t0 = None, -np.inf, [], time.time()
    for it in range(args.iters):
        pop = np.clip(mean + std * rng.standard_normal((args.pop, len(PARAMS))), LOW, HIGH)
        scores = np.array([evaluate(env, th, seed=args.seed)[0] for th in pop])
        elite = pop[np.argsort(scores)[-args.elite:]]
        mean, std = elite.mean(0), np.maximum(elite.std(0), 0.02 * (HIGH - LOW))
        if scores.max() > best_v:
            best_v, best = float(scores.max()), pop[int(np.argmax(scores))]
        history.append(round(float(scores.max()), 3))
        print(f"iter {it:2d}  best {scores.max():.3f}  elite mean {np.sort(scores)[-args.elite:].mean():.3f}  "
              f"overall {best_v:.3f}  {time.time() - t0:.0f}s", flush=True)
    checks = [evaluate(env, best, seed=s) for s in range(1, 11)]  # other resets: is the gait robust?
    result = {
        "best_speed_m_s": best_v,
        "best_params": {k: round(float(v), 4) for k, v in zip([q[0] for q in PARAMS], best)},
        "other_resets": {"speeds": [round(c[0], 3) for c in checks], "falls": sum(fell for _, fell in checks)},
        "per_iteration_best": history,
        "settings": vars(args),
        "wall_s": round(time.time() - t0, 1),
    }
    print(json.dumps(result, indent=1))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1)


if __name__ == "__main__":
    main()
