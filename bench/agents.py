"""Updates per second of every d5rl agent vs. a plain PyTorch (eager) version of the
same algorithm, networks and batch, measured in the same run.

    python bench/agents.py                       # all agents, state and pixels
    python bench/agents.py --agents iql td3bc --no-pixels --seconds 5

State: batch 256, 58-D observations, 12-D actions (A1-sized).  Pixels: batch 64,
two 64×64 cameras with 3 stacked frames (18 channels) + 9-D proprioception,
9-D actions, IMPALA encoders, DrQ augmentation.  RLPD runs UTD 20 (one update =
20 critic steps + 1 actor step) in both implementations.

JAX is timed as the training loop runs it: state agents do ``updates_per_call``
updates per jit call with ``lax.scan``; pixel agents one per call.  JAX runs with the
XLA flags ``import d5rl`` sets (d5rl/xla_flags.py; set them in ``XLA_FLAGS`` to compare).
Numbers are medians over alternating repeats (the machine may be shared).  Without torch
the reference column is empty.
"""

from __future__ import annotations

import argparse
import copy
import math
import os
import platform
import statistics
import sys
import time

import numpy as np

OBS_DIM, ACT_DIM, BATCH = 58, 12, 256
PIX, CAMS, STACK, PROPRIO, PIX_ACT, PIX_BATCH = 64, 2, 3, 9, 9, 64
KEYS = ("observations", "actions", "rewards", "masks", "next_observations", "mc_returns")


# ============================== data ==============================
def make_batch(n: int, pixels: bool, rng: np.random.Generator) -> dict:
    if pixels:
        def obs():
            o = {f"pixels/cam{i}": rng.integers(0, 256, (n, PIX, PIX, 3 * STACK), dtype=np.uint8) for i in range(CAMS)}
            o["proprio"] = rng.standard_normal((n, PROPRIO)).astype(np.float32)
            return o
        a_dim = PIX_ACT
    else:
        def obs():
            return rng.standard_normal((n, OBS_DIM)).astype(np.float32)
        a_dim = ACT_DIM
    return {"observations": obs(), "next_observations": obs(),
            "actions": rng.uniform(-0.99, 0.99, (n, a_dim)).astype(np.float32),
            "rewards": rng.standard_normal(n).astype(np.float32),
            "masks": (rng.random(n) > 0.01).astype(np.float32),
            "mc_returns": rng.standard_normal(n).astype(np.float32)}


# ============================== JAX side ==============================
def jax_runner(name: str, pixels: bool, k: int):
    import jax

    from d5rl.agents import get_agent

    cls, get_config = get_agent(name)
    cfg = get_config()
    if pixels:
        cfg = cfg.replace(batch_size=PIX_BATCH)
    utd = cfg.get("utd_ratio", 1)
    per = cfg.batch_size * utd
    rng = np.random.default_rng(0)
    ex = make_batch(1, pixels, rng)
    agent = cls.create(0, ex["observations"], ex["actions"], cfg)
    k = 1 if pixels else k
    batches = [make_batch(per * k, pixels, rng) for _ in range(2)]
    if k > 1:
        batches = [jax.tree_util.tree_map(lambda x: x.reshape((k, per) + x.shape[1:]), b) for b in batches]
        step = lambda a, b: a.update_many(b)  # noqa: E731
    else:
        step = lambda a, b: a.update_donated(b)  # noqa: E731
    state = {"agent": agent, "i": 0}

    def run(n_calls: int) -> int:
        a = state["agent"]
        for _ in range(n_calls):
            a, m = step(a, batches[state["i"] % 2])
            state["i"] += 1
        jax.block_until_ready(m)
        state["agent"] = a
        return n_calls * k

    return run


# ============================== PyTorch side ==============================
def torch_impala():
    """The IMPALA encoder in PyTorch (NCHW), as d5rl's ``ImpalaEncoder``: a class taking in-channels."""
    import torch
    import torch.nn as nn
    import torch.nn.functional as F

    class Impala(nn.Module):
        def __init__(self, in_ch, chans=(16, 32, 32)):
            super().__init__()
            self.stacks = nn.ModuleList()
            for ch in chans:
                self.stacks.append(nn.ModuleList([nn.Conv2d(in_ch, ch, 3, padding=1)] +
                                                 [nn.Conv2d(ch, ch, 3, padding=1) for _ in range(4)]))
                in_ch = ch

        def forward(self, x):
            for convs in self.stacks:
                x = convs[0](x)
                x = F.max_pool2d(x, 3, 2, padding=1)
                for j in (1, 3):
                    y = convs[j + 1](F.relu(convs[j](F.relu(x))))
                    x = x + y
            return torch.flatten(F.relu(x), 1)

    return Impala


def torch_runner(name: str, pixels: bool):
    import torch
    import torch.nn as nn
    import torch.nn.functional as F

    torch.manual_seed(0)

    class MLP(nn.Module):
        def __init__(self, sizes, layer_norm=False, act_final=False, act=nn.ReLU, dropout=0.0):
            super().__init__()
            layers = []
            for i in range(len(sizes) - 1):
                layers.append(nn.Linear(sizes[i], sizes[i + 1]))
                if i < len(sizes) - 2 or act_final:
                    if dropout:
                        layers.append(nn.Dropout(dropout))
                    if layer_norm:
                        layers.append(nn.LayerNorm(sizes[i + 1]))
                    layers.append(act())
            self.net = nn.Sequential(*layers)

        def forward(self, x):
            return self.net(x)

    class EnsembleLinear(nn.Module):
        def __init__(self, e, i, o):
            super().__init__()
            self.w = nn.Parameter(torch.randn(e, i, o) / math.sqrt(i))
            self.b = nn.Parameter(torch.zeros(e, 1, o))

        def forward(self, x):  # (E, B, i)
            return torch.baddbmm(self.b, x, self.w)

    class EnsembleMLP(nn.Module):
        def __init__(self, e, sizes, layer_norm=False):
            super().__init__()
            self.e = e
            self.lins = nn.ModuleList([EnsembleLinear(e, sizes[i], sizes[i + 1]) for i in range(len(sizes) - 1)])
            self.ln = layer_norm
            self.ln_w = nn.ParameterList([nn.Parameter(torch.ones(e, 1, s)) for s in sizes[1:-1]])
            self.ln_b = nn.ParameterList([nn.Parameter(torch.zeros(e, 1, s)) for s in sizes[1:-1]])

        def forward(self, x):
            x = x.unsqueeze(0).expand(self.e, *x.shape)
            for i, lin in enumerate(self.lins):
                x = lin(x)
                if i < len(self.lins) - 1:
                    if self.ln:
                        x = F.layer_norm(x, x.shape[-1:]) * self.ln_w[i] + self.ln_b[i]
                    x = F.relu(x)
            return x[..., 0]

    Impala = torch_impala()

    class Encoder(nn.Module):
        """Identity for states; IMPALA + Dense/LN/tanh + proprio for pixels."""

        def __init__(self):
            super().__init__()
            if pixels:
                self.cnn = Impala(3 * STACK * CAMS).to(memory_format=torch.channels_last)
                self.proj = nn.Linear(32 * 8 * 8, 50)
                self.ln = nn.LayerNorm(50)
                self.out_dim = 50 + PROPRIO
            else:
                self.out_dim = OBS_DIM

        def forward(self, obs):
            if not pixels:
                return obs
            img = torch.cat([obs[f"pixels/cam{i}"] for i in range(CAMS)], -1)
            img = img.permute(0, 3, 1, 2).float().div(255.0).contiguous(memory_format=torch.channels_last)
            h = torch.tanh(self.ln(self.proj(self.cnn(img))))
            return torch.cat([h, obs["proprio"]], -1)

    a_dim = PIX_ACT if pixels else ACT_DIM
    H = (256, 256)
    YIQ = torch.tensor([[0.299, 0.587, 0.114], [0.596, -0.274, -0.322], [0.211, -0.523, 0.312]])
    IYIQ = torch.linalg.inv(YIQ)

    def augment(obs):
        if not pixels:
            return obs
        out = dict(obs)
        for i in range(CAMS):
            img = obs[f"pixels/cam{i}"].permute(0, 3, 1, 2).float()
            b, c, h, w = img.shape
            pad = F.pad(img, (4, 4, 4, 4), mode="replicate")
            eps = 1.0 / (h + 8)
            ar = torch.linspace(-1.0 + eps, 1.0 - eps, h + 8)[:h]
            ar = ar.unsqueeze(0).repeat(h, 1).unsqueeze(2)
            base = torch.cat([ar, ar.transpose(1, 0)], 2).unsqueeze(0).repeat(b, 1, 1, 1)
            shift = torch.randint(0, 9, (b, 1, 1, 2)).float() * 2.0 / (h + 8)
            img = F.grid_sample(pad, base + shift, padding_mode="zeros", align_corners=False)
            x = img.reshape(b, STACK, 3, h, w) / 255.0
            x = x * torch.empty(b, 1, 1, 1, 1).uniform_(0.8, 1.2)
            g = (x * torch.tensor([0.299, 0.587, 0.114]).view(1, 1, 3, 1, 1)).sum(2, keepdim=True)
            m = g.mean(dim=(1, 2, 3, 4), keepdim=True)
            x = (x - m) * torch.empty(b, 1, 1, 1, 1).uniform_(0.8, 1.2) + m
            g = (x * torch.tensor([0.299, 0.587, 0.114]).view(1, 1, 3, 1, 1)).sum(2, keepdim=True)
            x = (x - g) * torch.empty(b, 1, 1, 1, 1).uniform_(0.8, 1.2) + g
            th = torch.empty(b).uniform_(-0.05, 0.05) * 2 * math.pi
            rot = torch.zeros(b, 3, 3)
            rot[:, 0, 0] = 1
            rot[:, 1, 1], rot[:, 1, 2], rot[:, 2, 1], rot[:, 2, 2] = th.cos(), -th.sin(), th.sin(), th.cos()
            mat = IYIQ @ rot @ YIQ
            x = torch.einsum("bscHW,bdc->bsdHW", x, mat)
            x = (x.clamp(0, 1) * 255).round().reshape(b, c, h, w)
            out[f"pixels/cam{i}"] = x.permute(0, 2, 3, 1).to(torch.uint8)
        return out

    class Critic(nn.Module):
        def __init__(self, n=2, ln=False):
            super().__init__()
            self.enc = Encoder()
            self.heads = EnsembleMLP(n, (self.enc.out_dim + a_dim,) + H + (1,), ln)

        def forward(self, obs, a):
            return self.heads(torch.cat([self.enc(obs), a], -1))

    class Value(nn.Module):
        def __init__(self):
            super().__init__()
            self.enc = Encoder()
            self.mlp = MLP((self.enc.out_dim,) + H + (1,))

        def forward(self, obs):
            return self.mlp(self.enc(obs))[..., 0]

    class Gauss(nn.Module):
        def __init__(self, tanh_squash, lmin=-5.0):
            super().__init__()
            self.enc = Encoder()
            self.trunk = MLP((self.enc.out_dim,) + H, act_final=True)
            self.mu = nn.Linear(H[-1], a_dim)
            self.ls = nn.Linear(H[-1], a_dim)
            self.tanh_squash, self.lmin = tanh_squash, lmin

        def forward(self, obs):
            h = self.trunk(self.enc(obs))
            mu = self.mu(h)
            return (mu if self.tanh_squash else torch.tanh(mu)), self.ls(h).clamp(self.lmin, 2.0)

    def normal_logp(x, mu, ls):
        return (-0.5 * ((x - mu) / ls.exp()) ** 2 - ls - 0.5 * math.log(2 * math.pi)).sum(-1)

    def tanh_sample(mu, ls):
        u = mu + ls.exp() * torch.randn_like(mu)
        logp = normal_logp(u, mu, ls) - (2 * (math.log(2) - u - F.softplus(-2 * u))).sum(-1)
        return torch.tanh(u), logp

    class Det(nn.Module):
        def __init__(self):
            super().__init__()
            self.enc = Encoder()
            self.mlp = MLP((self.enc.out_dim,) + H + (a_dim,))

        def forward(self, obs):
            return torch.tanh(self.mlp(self.enc(obs)))

    class Noise(nn.Module):
        def __init__(self):
            super().__init__()
            self.enc = Encoder()
            self.fw = nn.Parameter(torch.randn(32, 1) * 0.2)
            self.tmlp = MLP((64, 128, 128), act=nn.SiLU)
            self.inp = nn.Linear(self.enc.out_dim + a_dim + 128, 256)
            self.blocks = nn.ModuleList([nn.ModuleList([nn.Dropout(0.1), nn.LayerNorm(256), nn.Linear(256, 1024),
                                                        nn.Linear(1024, 256)]) for _ in range(3)])
            self.out = nn.Linear(256, a_dim)

        def forward(self, obs, x, t):
            f = 2 * math.pi * t @ self.fw.T
            te = self.tmlp(torch.cat([f.cos(), f.sin()], -1))
            h = self.inp(torch.cat([self.enc(obs), x, te], -1))
            for drop, ln, l1, l2 in self.blocks:
                h = h + l2(F.silu(l1(ln(drop(h)))))
            return self.out(F.silu(h))

    steps = torch.linspace(0, 20, 21) / 20
    ac = torch.cos((steps + 0.008) / 1.008 * math.pi / 2) ** 2
    ac = ac / ac[0]
    alpha_hat = torch.cumprod(1 - (1 - ac[1:] / ac[:-1]).clamp(0, 0.999), 0)

    def soft(target, online, tau=0.005):
        with torch.no_grad():
            for t, o in zip(target.parameters(), online.parameters()):
                t.lerp_(o, tau)

    def adam(m, lr=3e-4):
        return torch.optim.Adam(m.parameters(), lr=lr)

    def step(opt, loss):
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    def ddpm_loss(model, obs, a):
        t = torch.randint(0, 20, (a.shape[0],))
        noise = torch.randn_like(a)
        ah = alpha_hat[t].unsqueeze(-1)
        eps = model(obs, ah.sqrt() * a + (1 - ah).sqrt() * noise, t.float().unsqueeze(-1))
        return ((eps - noise) ** 2).sum(-1).mean()

    nets = {}
    if name == "bc":
        nets["actor"] = Gauss(False)
        opts = {"actor": adam(nets["actor"])}

        def update(b):
            mu, ls = nets["actor"](augment(b["observations"]))
            step(opts["actor"], -normal_logp(b["actions"], mu, ls).mean())
    elif name in ("iql", "idql"):
        nets["critic"], nets["value"] = Critic(), Value()
        nets["actor"] = Gauss(False) if name == "iql" else Noise()
        tgt = copy.deepcopy(nets["critic"])
        opts = {k: adam(v) for k, v in nets.items()}

        def update(b):
            b = {**b, "observations": augment(b["observations"]), "next_observations": augment(b["next_observations"])}
            with torch.no_grad():
                q = tgt(b["observations"], b["actions"]).min(0).values
            v = nets["value"](b["observations"])
            d = q - v
            step(opts["value"], (torch.where(d > 0, 0.7, 0.3) * d**2).mean())
            if name == "iql":
                with torch.no_grad():
                    w = torch.exp((q - nets["value"](b["observations"])) * 3.0).clamp(max=100)
                mu, ls = nets["actor"](b["observations"])
                step(opts["actor"], -(w * normal_logp(b["actions"], mu, ls)).mean())
            with torch.no_grad():
                target = b["rewards"] + 0.99 * b["masks"] * nets["value"](b["next_observations"])
            qs = nets["critic"](b["observations"], b["actions"])
            step(opts["critic"], ((qs - target) ** 2).mean(1).sum())
            if name == "idql":
                step(opts["actor"], ddpm_loss(nets["actor"], b["observations"], b["actions"]))
            soft(tgt, nets["critic"])
    elif name == "td3bc":
        nets["actor"], nets["critic"] = Det(), Critic()
        ta, tc = copy.deepcopy(nets["actor"]), copy.deepcopy(nets["critic"])
        opts = {k: adam(v) for k, v in nets.items()}
        it = {"n": 0}

        def update(b):
            b = {**b, "observations": augment(b["observations"]), "next_observations": augment(b["next_observations"])}
            with torch.no_grad():
                na = ta(b["next_observations"])
                na = (na + (0.2 * torch.randn_like(na)).clamp(-0.5, 0.5)).clamp(-1, 1)
                target = b["rewards"] + 0.99 * b["masks"] * tc(b["next_observations"], na).min(0).values
            step(opts["critic"], ((nets["critic"](b["observations"], b["actions"]) - target) ** 2).mean(1).sum())
            it["n"] += 1
            if it["n"] % 2 == 1:
                pi = nets["actor"](b["observations"])
                q = nets["critic"](b["observations"], pi)[0]
                lam = 2.5 / q.abs().mean().detach()
                step(opts["actor"], -lam * q.mean() + ((pi - b["actions"]) ** 2).mean())
                soft(ta, nets["actor"])
                soft(tc, nets["critic"])
    elif name in ("cql", "calql", "rlpd"):
        rlpd = name == "rlpd"
        nets["actor"] = Gauss(True, lmin=-20.0)
        nets["critic"] = Critic(10 if rlpd else 2, ln=rlpd)
        tc = copy.deepcopy(nets["critic"])
        log_t = torch.zeros((), requires_grad=True)
        opts = {"actor": adam(nets["actor"], 3e-4 if rlpd else 1e-4), "critic": adam(nets["critic"]),
                "temp": torch.optim.Adam([log_t], lr=3e-4)}
        target_ent = -a_dim / 2 if rlpd else -a_dim
        utd = 20 if rlpd else 1

        def critic_step(b):
            with torch.no_grad():
                na, nlp = tanh_sample(*nets["actor"](b["next_observations"]))
                tq = tc(b["next_observations"], na)
                if rlpd:
                    tq = tq[torch.randperm(10)[:2]].min(0).values - log_t.exp() * nlp
                else:
                    tq = tq.min(0).values
                target = b["rewards"] + 0.99 * b["masks"] * tq
            feats = nets["critic"].enc(b["observations"])
            qs = nets["critic"].heads(torch.cat([feats, b["actions"]], -1))
            loss = ((qs - target) ** 2).mean() if rlpd else ((qs - target) ** 2).mean(1).sum()
            if not rlpd:
                n, bs = 10, b["actions"].shape[0]
                with torch.no_grad():
                    mu, ls = nets["actor"](b["observations"])
                    cur, clp = tanh_sample(mu.expand(n, *mu.shape), ls.expand(n, *ls.shape))
                    mu2, ls2 = nets["actor"](b["next_observations"])
                    nxt, nlp2 = tanh_sample(mu2.expand(n, *mu2.shape), ls2.expand(n, *ls2.shape))
                rand = torch.rand(n, bs, a_dim) * 2 - 1
                f = feats.expand(n, *feats.shape).reshape(n * bs, -1)

                def q_of(a):
                    return nets["critic"].heads(torch.cat([f, a.reshape(n * bs, -1)], -1)).reshape(2, n, bs)

                qc, qn = q_of(cur), q_of(nxt)
                if name == "calql":
                    lb = b["mc_returns"].view(1, 1, -1)
                    qc, qn = torch.maximum(qc, lb), torch.maximum(qn, lb)
                cat = torch.cat([q_of(rand) - a_dim * math.log(0.5), qn - nlp2, qc - clp], 1)
                loss = loss + 5.0 * (torch.logsumexp(cat, 1) - qs).mean(1).sum()
            step(opts["critic"], loss)
            soft(tc, nets["critic"])

        def actor_step(b):
            a, lp = tanh_sample(*nets["actor"](b["observations"]))
            qs = nets["critic"](b["observations"], a)
            q = qs.mean(0) if rlpd else qs.min(0).values
            step(opts["actor"], (log_t.exp().detach() * lp - q).mean())
            ent = -lp.detach().mean()
            step(opts["temp"], log_t.exp() * (ent - target_ent))

        def update(b):
            b = {**b, "observations": augment(b["observations"]), "next_observations": augment(b["next_observations"])}
            bs = b["actions"].shape[0] // utd
            mb = None
            if not rlpd:
                actor_step(b)
            for i in range(utd):
                mb = {k: ({kk: vv[i * bs:(i + 1) * bs] for kk, vv in v.items()} if isinstance(v, dict)
                          else v[i * bs:(i + 1) * bs]) for k, v in b.items()}
                critic_step(mb)
            if rlpd:
                actor_step(mb)
    elif name == "ddpm_bc":
        nets["actor"] = Noise()
        ema = copy.deepcopy(nets["actor"])
        opts = {"actor": adam(nets["actor"])}

        def update(b):
            step(opts["actor"], ddpm_loss(nets["actor"], augment(b["observations"]), b["actions"]))
            soft(ema, nets["actor"], 0.001)
    else:
        raise KeyError(name)

    for m in nets.values():
        m.train()
    utd = 20 if name == "rlpd" else 1
    bs = (PIX_BATCH if pixels else BATCH) * utd
    rng = np.random.default_rng(0)

    def to_t(b):
        return {k: ({kk: torch.from_numpy(vv) for kk, vv in v.items()} if isinstance(v, dict) else torch.from_numpy(v))
                for k, v in b.items()}

    batches = [to_t(make_batch(bs, pixels, rng)) for _ in range(2)]
    state = {"i": 0}

    def run(n: int) -> int:
        for _ in range(n):
            update(batches[state["i"] % 2])
            state["i"] += 1
        return n

    return run


# ============================== timing ==============================
def rate(run, seconds: float) -> float:
    """Updates per second: run in growing chunks until ``seconds`` have passed."""
    n_calls, done, t0 = 1, 0, time.perf_counter()
    while True:
        done += run(n_calls)
        el = time.perf_counter() - t0
        if el >= seconds:
            return done / el
        n_calls = max(1, min(n_calls * 2, int(n_calls * seconds / max(el, 1e-3))))


def main(argv=None) -> int:
    from d5rl.agents import AGENTS

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--agents", nargs="*", default=list(AGENTS))
    p.add_argument("--no-pixels", action="store_true")
    p.add_argument("--no-state", action="store_true")
    p.add_argument("--seconds", type=float, default=4.0, help="per measurement")
    p.add_argument("--repeats", type=int, default=3, help="alternating JAX / torch repeats (median)")
    p.add_argument("--updates-per-call", type=int, default=8, help="lax.scan length for state agents")
    p.add_argument("--torch-threads", type=int, default=0,
                   help="torch intra-op threads; 0 = try 1 and all CPUs per case and keep the faster")
    args = p.parse_args(argv)
    try:
        import torch

        ref_name = f"torch {torch.__version__} eager"
    except ImportError:
        torch = None
        ref_name = None
    import jax

    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, jax {jax.__version__} "
          f"({jax.default_backend()}), reference: {ref_name or 'none (torch not installed)'}")
    print(f"{'agent':10s} {'obs':6s} {'jax upd/s':>10s} {'torch upd/s':>12s} {'ratio':>6s} {'torch thr':>9s}")
    kinds = ([False] if not args.no_state else []) + ([True] if not args.no_pixels else [])
    worst = math.inf
    for pixels in kinds:
        for name in args.agents:
            jr = jax_runner(name, pixels, args.updates_per_call)
            jr(1)  # compile
            tr = torch_runner(name, pixels) if torch is not None else None
            threads = args.torch_threads
            if tr is not None:
                tr(1)
                if not threads:  # give the reference its best thread count on this (possibly shared) machine
                    trial = {}
                    for n in sorted({1, os.cpu_count() or 1}):
                        torch.set_num_threads(n)
                        trial[n] = rate(tr, min(1.0, args.seconds))
                    threads = max(trial, key=trial.get)
                torch.set_num_threads(threads)
            js, ts = [], []
            for _ in range(args.repeats):
                js.append(rate(jr, args.seconds))
                if tr is not None:
                    ts.append(rate(tr, args.seconds))
            j = statistics.median(js)
            t = statistics.median(ts) if ts else float("nan")
            ratio = j / t if ts else float("nan")
            worst = min(worst, ratio) if ts else worst
            print(f"{name:10s} {'pixels' if pixels else 'state':6s} {j:10.1f} {t:12.1f} {ratio:6.2f} {threads:9d}",
                  flush=True)
    if math.isfinite(worst):
        print(f"# slowest ratio: {worst:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
