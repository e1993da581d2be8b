"""Plain eager-PyTorch versions of d5rl's agents: the baselines ``bench/agents.py`` measures
d5rl against.  Same networks, batch and update order as each d5rl agent (defaults of its
``get_config()``), written the way a PyTorch user would (channels-last images, one optimizer
step per loss).  ``make_kit(pixels)`` builds the shared pieces; one builder per algorithm
returns ``(networks, update(batch))``.
"""

from __future__ import annotations

import copy
import math
from types import SimpleNamespace

import numpy as np

# The benchmark's sizes (bench/agents.py documents them): A1-sized states, two 64x64 cameras.
OBS_DIM, ACT_DIM = 58, 12
CAMS, STACK, PROPRIO, PIX_ACT = 2, 3, 9, 9


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
                self.stacks.append(
                    nn.ModuleList(
                        [nn.Conv2d(in_ch, ch, 3, padding=1)] + [nn.Conv2d(ch, ch, 3, padding=1) for _ in range(4)]
                    )
                )
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


def make_kit(pixels: bool) -> SimpleNamespace:
    """The reference's building blocks for state (``pixels=False``) or camera observations."""
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
        def __init__(self, n=2, ln=False, hidden=None):
            super().__init__()
            self.enc = Encoder()
            self.heads = EnsembleMLP(n, (self.enc.out_dim + a_dim,) + tuple(hidden or H) + (1,), ln)

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
        def __init__(self, hidden=None):
            super().__init__()
            self.enc = Encoder()
            self.mlp = MLP((self.enc.out_dim,) + tuple(hidden or H) + (a_dim,))

        def forward(self, obs):
            return torch.tanh(self.mlp(self.enc(obs)))

    class Field(nn.Module):
        """MLP on concat(encoded obs, x[, t]) -> a_dim (FQL's flow and one-step policy)."""

        def __init__(self, hidden, time=False):
            super().__init__()
            self.enc = Encoder()
            self.mlp = MLP((self.enc.out_dim + a_dim + int(time),) + tuple(hidden) + (a_dim,))

        def forward(self, obs, x, t=None):
            return self.mlp(torch.cat([self.enc(obs), x] + ([t] if t is not None else []), -1))

    class Noise(nn.Module):
        def __init__(self):
            super().__init__()
            self.enc = Encoder()
            self.fw = nn.Parameter(torch.randn(32, 1) * 0.2)
            self.tmlp = MLP((64, 128, 128), act=nn.SiLU)
            self.inp = nn.Linear(self.enc.out_dim + a_dim + 128, 256)
            self.blocks = nn.ModuleList(
                [
                    nn.ModuleList([nn.Dropout(0.1), nn.LayerNorm(256), nn.Linear(256, 1024), nn.Linear(1024, 256)])
                    for _ in range(3)
                ]
            )
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

    return SimpleNamespace(
        torch=torch,
        nn=nn,
        F=F,
        MLP=MLP,
        Encoder=Encoder,
        a_dim=a_dim,
        H=H,
        augment=augment,
        Critic=Critic,
        Value=Value,
        Gauss=Gauss,
        Det=Det,
        Field=Field,
        Noise=Noise,
        normal_logp=normal_logp,
        tanh_sample=tanh_sample,
        soft=soft,
        adam=adam,
        step=step,
        ddpm_loss=ddpm_loss,
    )


# --- one builder per algorithm: (kit) -> (networks, update(batch)) ------------------------------------------
def _augmented(k, b):
    return {**b, "observations": k.augment(b["observations"]), "next_observations": k.augment(b["next_observations"])}


def bc(k):
    nets = {"actor": k.Gauss(False)}
    opt = k.adam(nets["actor"])

    def update(b):
        mu, ls = nets["actor"](k.augment(b["observations"]))
        k.step(opt, -k.normal_logp(b["actions"], mu, ls).mean())

    return nets, update


def _iql_like(k, diffusion: bool):
    torch = k.torch
    nets = {"critic": k.Critic(), "value": k.Value(), "actor": k.Noise() if diffusion else k.Gauss(False)}
    tgt = copy.deepcopy(nets["critic"])
    opts = {n: k.adam(m) for n, m in nets.items()}

    def update(b):
        b = _augmented(k, b)
        with torch.no_grad():
            q = tgt(b["observations"], b["actions"]).min(0).values
        v = nets["value"](b["observations"])
        d = q - v
        k.step(opts["value"], (torch.where(d > 0, 0.7, 0.3) * d**2).mean())
        if not diffusion:
            with torch.no_grad():
                w = torch.exp((q - nets["value"](b["observations"])) * 3.0).clamp(max=100)
            mu, ls = nets["actor"](b["observations"])
            k.step(opts["actor"], -(w * k.normal_logp(b["actions"], mu, ls)).mean())
        with torch.no_grad():
            target = b["rewards"] + 0.99 * b["masks"] * nets["value"](b["next_observations"])
        qs = nets["critic"](b["observations"], b["actions"])
        k.step(opts["critic"], ((qs - target) ** 2).mean(1).sum())
        if diffusion:
            k.step(opts["actor"], k.ddpm_loss(nets["actor"], b["observations"], b["actions"]))
        k.soft(tgt, nets["critic"])

    return nets, update


def iql(k):
    return _iql_like(k, diffusion=False)


def idql(k):
    return _iql_like(k, diffusion=True)


def _td3_like(k, rebrac: bool):
    """TD3+BC, or ReBRAC: LayerNorm critics, 3 hidden layers, penalties on both sides, lr 1e-3."""
    torch = k.torch
    hidden = (256, 256, 256) if rebrac else None
    nets = {"actor": k.Det(hidden), "critic": k.Critic(ln=rebrac, hidden=hidden)}
    ta, tc = copy.deepcopy(nets["actor"]), copy.deepcopy(nets["critic"])
    lr = 1e-3 if rebrac else 3e-4
    opts = {n: k.adam(m, lr) for n, m in nets.items()}
    it = {"n": 0}

    def update(b):
        b = _augmented(k, b)
        with torch.no_grad():
            na = ta(b["next_observations"])
            na = (na + (0.2 * torch.randn_like(na)).clamp(-0.5, 0.5)).clamp(-1, 1)
            nq = tc(b["next_observations"], na).min(0).values
            if rebrac:
                nq = nq - 0.01 * ((na - b["next_actions"]) ** 2).sum(-1)
            target = b["rewards"] + 0.99 * b["masks"] * nq
        k.step(opts["critic"], ((nets["critic"](b["observations"], b["actions"]) - target) ** 2).mean(1).sum())
        it["n"] += 1
        if it["n"] % 2 == 1:
            pi = nets["actor"](b["observations"])
            qs = nets["critic"](b["observations"], pi)
            if rebrac:
                q = qs.min(0).values
                loss = (0.01 * ((pi - b["actions"]) ** 2).sum(-1) - q / q.abs().mean().detach()).mean()
            else:
                q = qs[0]
                loss = -2.5 / q.abs().mean().detach() * q.mean() + ((pi - b["actions"]) ** 2).mean()
            k.step(opts["actor"], loss)
            k.soft(ta, nets["actor"])
            k.soft(tc, nets["critic"])

    return nets, update


def td3bc(k):
    return _td3_like(k, rebrac=False)


def rebrac(k):
    return _td3_like(k, rebrac=True)


def _sac_like(k, name: str):
    """CQL, Cal-QL (conservative critic, 10 sampled actions of each kind) or RLPD (10 LayerNorm critics, UTD 20)."""
    torch, a_dim = k.torch, k.a_dim
    rlpd = name == "rlpd"
    nets = {"actor": k.Gauss(True, lmin=-20.0), "critic": k.Critic(10 if rlpd else 2, ln=rlpd)}
    tc = copy.deepcopy(nets["critic"])
    log_t = torch.zeros((), requires_grad=True)
    opts = {
        "actor": k.adam(nets["actor"], 3e-4 if rlpd else 1e-4),
        "critic": k.adam(nets["critic"]),
        "temp": torch.optim.Adam([log_t], lr=3e-4),
    }
    target_ent = -a_dim / 2 if rlpd else -a_dim
    utd = 20 if rlpd else 1

    def critic_step(b):
        with torch.no_grad():
            na, nlp = k.tanh_sample(*nets["actor"](b["next_observations"]))
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
                cur, clp = k.tanh_sample(mu.expand(n, *mu.shape), ls.expand(n, *ls.shape))
                mu2, ls2 = nets["actor"](b["next_observations"])
                nxt, nlp2 = k.tanh_sample(mu2.expand(n, *mu2.shape), ls2.expand(n, *ls2.shape))
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
        k.step(opts["critic"], loss)
        k.soft(tc, nets["critic"])

    def actor_step(b):
        a, lp = k.tanh_sample(*nets["actor"](b["observations"]))
        qs = nets["critic"](b["observations"], a)
        q = qs.mean(0) if rlpd else qs.min(0).values
        k.step(opts["actor"], (log_t.exp().detach() * lp - q).mean())
        ent = -lp.detach().mean()
        k.step(opts["temp"], log_t.exp() * (ent - target_ent))

    def update(b):
        b = _augmented(k, b)
        bs = b["actions"].shape[0] // utd
        mb = None
        if not rlpd:
            actor_step(b)
        for i in range(utd):
            mb = {
                key: (
                    {kk: vv[i * bs : (i + 1) * bs] for kk, vv in v.items()}
                    if isinstance(v, dict)
                    else v[i * bs : (i + 1) * bs]
                )
                for key, v in b.items()
            }
            critic_step(mb)
        if rlpd:
            actor_step(mb)

    return nets, update


def cql(k):
    return _sac_like(k, "cql")


def calql(k):
    return _sac_like(k, "calql")


def rlpd(k):
    return _sac_like(k, "rlpd")


def ddpm_bc(k):
    nets = {"actor": k.Noise()}
    ema = copy.deepcopy(nets["actor"])
    opt = k.adam(nets["actor"])

    def update(b):
        k.step(opt, k.ddpm_loss(nets["actor"], k.augment(b["observations"]), b["actions"]))
        k.soft(ema, nets["actor"], 0.001)

    return nets, update


def fql(k):
    """Flow Q-learning: a behaviour flow (flow matching), a one-step policy distilled from it while
    maximising Q, two LayerNorm critics averaged in the target; 4x512 MLPs, lr 3e-4, alpha 10."""
    torch = k.torch
    hidden = (512, 512, 512, 512)
    nets = {"flow": k.Field(hidden, time=True), "actor": k.Field(hidden), "critic": k.Critic(ln=True, hidden=hidden)}
    tc = copy.deepcopy(nets["critic"])
    opts = {n: k.adam(m) for n, m in nets.items()}

    def update(b):
        b = _augmented(k, b)
        obs, a = b["observations"], b["actions"]
        with torch.no_grad():
            na = nets["actor"](b["next_observations"], torch.randn_like(a)).clamp(-1, 1)
            target = b["rewards"] + 0.99 * b["masks"] * tc(b["next_observations"], na).mean(0)
        k.step(opts["critic"], ((nets["critic"](obs, a) - target) ** 2).mean())
        z, t = torch.randn_like(a), torch.rand(a.shape[0], 1)
        k.step(opts["flow"], ((nets["flow"](obs, (1 - t) * z + t * a, t) - (a - z)) ** 2).mean())
        z = torch.randn_like(a)
        with torch.no_grad():
            x = z
            for i in range(10):
                x = x + nets["flow"](obs, x, torch.full((a.shape[0], 1), i / 10)) / 10
            x = x.clamp(-1, 1)
        mu = nets["actor"](obs, z)
        q = nets["critic"](obs, mu.clamp(-1, 1)).mean(0)
        k.step(opts["actor"], 10.0 * ((mu - x) ** 2).mean() - q.mean())
        k.soft(tc, nets["critic"])

    return nets, update


BUILDERS = {f.__name__: f for f in (bc, iql, cql, calql, td3bc, rlpd, ddpm_bc, idql, fql, rebrac)}
BATCH_MULTIPLIER = {"rlpd": 20}  # RLPD's update consumes UTD 20 minibatches


def torch_runner(name: str, pixels: bool, make_batch, batch_size: int):
    """``run(n)``: ``n`` updates of the reference ``name`` on two alternating batches from ``make_batch``."""
    import torch

    torch.manual_seed(0)
    nets, update = BUILDERS[name](make_kit(pixels))
    for m in nets.values():
        m.train()
    rng = np.random.default_rng(0)
    bs = batch_size * BATCH_MULTIPLIER.get(name, 1)

    def to_t(b):
        return {
            key: ({kk: torch.from_numpy(vv) for kk, vv in v.items()} if isinstance(v, dict) else torch.from_numpy(v))
            for key, v in b.items()
        }

    batches = [to_t(make_batch(bs, pixels, rng)) for _ in range(2)]
    state = {"i": 0}

    def run(n: int) -> int:
        for _ in range(n):
            update(batches[state["i"] % 2])
            state["i"] += 1
        return n

    return run
