"""Every agent's losses against values computed independently in numpy, on a tiny fixed batch.

"The loss falls" lets a sign or coefficient error through; these do not.  The networks' forward
passes are recomputed in float64 numpy from the agents' own parameters; random draws inside a loss
(policy samples, target noise, diffusion steps) are taken from the same keys, the way the agent
splits them, and everything done with them is recomputed here.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from d5rl.agents import get_agent
from d5rl.agents.diffusion import cosine_beta_schedule

B, OBS, ACT = 5, 3, 2
RTOL = 2e-4


def batch(seed=0):
    rng = np.random.default_rng(seed)
    return {
        "observations": rng.normal(size=(B, OBS)).astype(np.float32),
        "next_observations": rng.normal(size=(B, OBS)).astype(np.float32),
        "actions": rng.uniform(-0.9, 0.9, (B, ACT)).astype(np.float32),
        "rewards": rng.normal(size=B).astype(np.float32),
        "masks": np.array([1, 1, 0, 1, 1], np.float32),
        "mc_returns": rng.normal(size=B).astype(np.float32),
    }


def make(name, **kw):
    cls, config_fn = get_agent(name)
    cfg = config_fn()
    sizes = {"hidden_dims": (8, 8)} if "hidden_dims" in cfg else {}
    cfg = cfg.replace(**{**sizes, **kw})
    ex = batch()
    return cls.create(0, ex["observations"][:1], ex["actions"][:1], cfg)


# --- numpy forward passes of the agents' networks ---------------------------------------------------------
def P(tree):
    return jax.tree_util.tree_map(lambda x: np.asarray(x, np.float64), tree)


relu = lambda x: np.maximum(x, 0)  # noqa: E731


def layer_norm(p, x, eps=1e-6):
    mu, var = x.mean(-1, keepdims=True), x.var(-1, keepdims=True)
    return (x - mu) / np.sqrt(var + eps) * p["scale"] + p["bias"]


def mlp(p, x, n_layers, activate_final=False, ln=False):
    for i in range(n_layers):
        d = p[f"Dense_{i}"]
        x = x @ d["kernel"] + d["bias"]
        if i + 1 < n_layers or activate_final:
            if ln:
                x = layer_norm(p[f"LayerNorm_{i}"], x)
            x = relu(x)
    return x


def critic(p, obs, act, ln=False):
    """(num_qs, B): every head of the ensemble on concat(obs, act)."""
    heads = P(p)["heads"]["VmapMLP_0"]
    n = len([k for k in heads if k.startswith("Dense")])
    x = np.concatenate([obs, act], -1).astype(np.float64)
    out = []
    for q in range(heads["Dense_0"]["kernel"].shape[0]):
        out.append(mlp(jax.tree_util.tree_map(lambda a: a[q], heads), x, n, ln=ln)[..., 0])
    return np.stack(out)


def deterministic_actor(params, obs):
    """(B, act): tanh of the deterministic actor's output (TD3+BC, ReBRAC)."""
    p = P(params)
    h = mlp(p["MLP_0"], obs.astype(np.float64), len(p["MLP_0"]), activate_final=True)
    return np.tanh(h @ p["Dense_0"]["kernel"] + p["Dense_0"]["bias"])


def value(p, obs):
    p = P(p)["MLP_0"]
    return mlp(p, obs.astype(np.float64), len(p))[..., 0]


def gaussian(p, obs, cfg, tanh_squash):
    """(loc, log_std) of the GaussianPolicy."""
    p = P(p)
    h = mlp(p["MLP_0"], obs.astype(np.float64), len(p["MLP_0"]), activate_final=True)
    loc = h @ p["Dense_0"]["kernel"] + p["Dense_0"]["bias"]
    log_std = (
        h @ p["Dense_1"]["kernel"] + p["Dense_1"]["bias"]
        if "Dense_1" in p
        else np.broadcast_to(p["log_std"], loc.shape)
    )
    log_std = np.clip(log_std, cfg.log_std_min, cfg.log_std_max)
    return (loc if tanh_squash else np.tanh(loc)), log_std


def normal_logp(loc, log_std, u):
    return np.sum(-0.5 * ((u - loc) / np.exp(log_std)) ** 2 - log_std - 0.5 * math.log(2 * math.pi), -1)


def tanh_sample(loc, log_std, eps):
    """A tanh-squashed sample and its log-density (change of variables)."""
    u = loc + np.exp(log_std) * eps
    a = np.tanh(u)
    return a, normal_logp(loc, log_std, u) - np.sum(np.log(1 - a**2), -1)


def logsumexp(x, axis):
    m = x.max(axis=axis, keepdims=True)
    return (m + np.log(np.exp(x - m).sum(axis=axis, keepdims=True))).squeeze(axis)


def close(got, want):
    np.testing.assert_allclose(float(got), float(want), rtol=RTOL, atol=1e-5)


# --- BC, IQL, IDQL ------------------------------------------------------------------------------------------
def test_bc_loss_is_least_squares_on_a_tanh_mean_with_unit_std():
    """The release's BC (``UnitStdNormalPolicy``):
    -log N(a; tanh(f(s)), I) = ½‖a − tanh(f(s))‖² + (d/2)·log 2π."""
    agent, b = make("bc"), batch()
    loss, info = agent.actor_loss(agent.actor.params, b, jax.random.PRNGKey(1))
    p = P(agent.actor.params)
    assert set(p) == {"MLP_0", "Dense_0"}  # a mean head only: no std parameters
    mean = np.tanh(
        mlp(p["MLP_0"], b["observations"].astype(np.float64), 2, activate_final=True) @ p["Dense_0"]["kernel"]
        + p["Dense_0"]["bias"]
    )
    sq = ((mean - b["actions"]) ** 2).sum(-1)
    close(loss, (0.5 * sq + 0.5 * ACT * math.log(2 * math.pi)).mean())
    close(info["actor/mse"], sq.mean())
    close(info["actor/log_std"], 0.0)


def test_bc_learned_std_variant_is_the_negative_log_likelihood():
    agent, b = make("bc", learned_std=True), batch()
    loss, info = agent.actor_loss(agent.actor.params, b, jax.random.PRNGKey(1))
    loc, log_std = gaussian(agent.actor.params, b["observations"], agent.config, tanh_squash=False)
    close(loss, -normal_logp(loc, log_std, b["actions"]).mean())
    close(info["actor/mse"], ((loc - b["actions"]) ** 2).sum(-1).mean())


def test_bc_dropout_acts_in_training_only():
    agent, b = make("bc", dropout_rate=0.5), batch()
    losses = {float(agent.actor_loss(agent.actor.params, b, jax.random.PRNGKey(k))[0]) for k in range(3)}
    assert len(losses) == 3  # a new dropout mask per key
    plain = make("bc", dropout_rate=0.0)
    ev = np.asarray(agent.eval_actions(b["observations"]))
    np.testing.assert_allclose(ev, np.asarray(plain.eval_actions(b["observations"])), rtol=1e-6)  # same init


def test_bc_learning_rate_follows_the_release_cosine():
    """Cosine decay over the release's horizon: an offline-only run of N updates decays over 2N (the release's
    scripts budget 500k online updates after 500k offline ones also when they train offline only)."""
    from d5rl.agents.bc import BCAgent

    cfg = BCAgent.resolve_config(make("bc").config, offline_steps=10, online_steps=0)
    assert cfg.actor_decay_steps == 20
    assert BCAgent.resolve_config(make("bc").config, offline_steps=10, online_steps=30).actor_decay_steps == 40
    # wired into the optimizer: with a horizon of one update the second update moves nothing (its lr is 0),
    # with a constant lr it does
    for steps, moves in ((1, False), (0, True)):
        agent, b = make("bc", actor_lr=1e-3, actor_decay_steps=steps), batch()
        once = agent.update(b)[0]
        twice = once.update(b)[0]
        moved = any(
            np.abs(np.asarray(x) - np.asarray(y)).max() > 0
            for x, y in zip(jax.tree_util.tree_leaves(once.actor.params), jax.tree_util.tree_leaves(twice.actor.params))
        )
        assert moved == moves, steps


@pytest.mark.parametrize("name", ["iql", "idql"])
def test_iql_value_and_critic_losses(name):
    kw = {"critic_hidden_dims": (8, 8), "hidden_dim": 8, "num_blocks": 1} if name == "idql" else {}
    agent, b = make(name, expectile=0.8, discount=0.9, **kw), batch()
    q = critic(agent.target_critic_params, b["observations"], b["actions"]).min(0)
    v = value(agent.value.params, b["observations"])
    diff = q - v
    close(agent.value_loss(agent.value.params, b)[0], np.mean(np.where(diff > 0, 0.8, 0.2) * diff**2))
    target = b["rewards"] + 0.9 * b["masks"] * value(agent.value.params, b["next_observations"])
    qs = critic(agent.critic.params, b["observations"], b["actions"])
    close(agent.critic_loss(agent.critic.params, b)[0], ((qs - target) ** 2).mean(1).sum())


def test_iql_actor_loss_is_advantage_weighted_regression():
    agent, b = make("iql", temperature=3.0, max_weight=2.0), batch()
    loss, _ = agent.actor_loss(agent.actor.params, b, jax.random.PRNGKey(2))
    adv = critic(agent.target_critic_params, b["observations"], b["actions"]).min(0) - value(
        agent.value.params, b["observations"]
    )
    w = np.minimum(np.exp(3.0 * adv), 2.0)
    loc, log_std = gaussian(agent.actor.params, b["observations"], agent.config, tanh_squash=False)
    close(loss, -(w * normal_logp(loc, log_std, b["actions"])).mean())


def test_idql_takes_two_actor_steps_per_critic_step():
    """The release's IDQL: per update, one value and one critic step on the batch and two actor steps, on its
    first and second halves, each followed by the EMA of the sampling weights."""
    from d5rl.agents.networks import soft_update

    agent = make("idql", critic_hidden_dims=(8, 8), hidden_dim=8, num_blocks=1, batch_size=6, augment=False)
    rng = np.random.default_rng(3)
    b = {
        **batch(),
        "observations": rng.normal(size=(6, OBS)).astype(np.float32),
        "next_observations": rng.normal(size=(6, OBS)).astype(np.float32),
        "actions": rng.uniform(-0.9, 0.9, (6, ACT)).astype(np.float32),
        "rewards": np.ones(6, np.float32),
        "masks": np.ones(6, np.float32),
        "mc_returns": np.zeros(6, np.float32),
    }
    new, _ = agent.update(b)
    _, _, k1, k2 = jax.random.split(agent.rng, 4)
    actor, ema = agent.actor, agent.target_actor_params
    for part, key in (({k: v[:3] for k, v in b.items()}, k1), ({k: v[3:] for k, v in b.items()}, k2)):
        g, _ = jax.grad(agent.actor_loss, has_aux=True)(actor.params, part, key)
        actor = actor.apply_gradients(grads=g)
        ema = soft_update(ema, actor.params, agent.config.actor_ema)
    # The jitted update and these eager gradients round differently in the last bits, and Adam's first step
    # (g / (|g| + eps)) magnifies that where a gradient is near eps: up to 8e-6 seen on an AMD EPYC. A wrong
    # schedule (one step on the whole batch, the whole batch twice, the halves' keys swapped) is >= 9e-4 away.
    for got, want in zip(
        jax.tree_util.tree_leaves((new.actor.params, new.target_actor_params)),
        jax.tree_util.tree_leaves((actor.params, ema)),
    ):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=0, atol=5e-5)
    assert int(new.actor.step) == 2 and int(new.critic.step) == 1


@pytest.mark.parametrize("name", ["ddpm_bc", "idql"])
def test_diffusion_lr_decays_over_the_release_horizon(name):
    """Actor lr 3e-4 with a cosine over the release's offline + online updates (500k + 500k in its scripts, also
    for offline-only runs: an offline-only run of N updates decays over 2N)."""
    from d5rl.settings import resolve

    for task in ("kitchen-standard-mixed-v0", "wx-sorting-v0", "a1-walk-v0", "kitchen-standard-mixed-state-v0"):
        cfg = resolve(name, task, offline_steps=500_000).agent
        assert (cfg.actor_lr, cfg.actor_decay_steps) == (3e-4, 1_000_000), task
    assert resolve(name, "a1-walk-v0", offline_steps=100, online_steps=50).agent.actor_decay_steps == 150


# --- CQL and Cal-QL -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("form", ["release", "paper"])
@pytest.mark.parametrize("name", ["cql", "calql"])
def test_cql_critic_loss(name, form):
    """release (the default; ``critic_updater.py``): the log-sum-exp over uniform and π(s) actions, the TD target
    the best of n actions of π(s') (max-Q backup); paper: π(s') actions in the log-sum-exp too, one-sample
    TD target."""
    release = form == "release"
    agent = make(
        name, cql_n_actions=3, cql_alpha=2.0, discount=0.9, cql_next_actions=not release, cql_max_target_backup=release
    )
    b, key = batch(), jax.random.PRNGKey(3)
    loss, info = agent.critic_loss(agent.critic.params, b, key)
    cfg, n = agent.config, 3
    k_next, k_rand, k_cur, k_nxt = jax.random.split(key, 4)
    obs, nobs = b["observations"], b["next_observations"]
    loc_s, ls_s = gaussian(agent.actor.params, obs, cfg, tanh_squash=True)
    loc_n, ls_n = gaussian(agent.actor.params, nobs, cfg, tanh_squash=True)
    # TD: r + γ·mask·min_i Q_target_i(s', a') (no entropy backup in CQL); release: max over n draws a' ~ π(s')
    if release:
        a_next, _ = tanh_sample(loc_n, ls_n, np.asarray(jax.random.normal(k_next, (n, B, ACT)), np.float64))
        next_q = np.stack([critic(agent.target_critic_params, nobs, a_next[i]).min(0) for i in range(n)]).max(0)
    else:
        a_next, _ = tanh_sample(loc_n, ls_n, np.asarray(jax.random.normal(k_next, (B, ACT)), np.float64))
        next_q = critic(agent.target_critic_params, nobs, a_next).min(0)
    target = b["rewards"] + 0.9 * b["masks"] * next_q
    qs = critic(agent.critic.params, obs, b["actions"])
    td = ((qs - target) ** 2).mean(1).sum()
    # conservative term: importance-sampled log-sum-exp over uniform and π(s) actions (paper: and π(s'))
    rand = np.asarray(jax.random.uniform(k_rand, (n, B, ACT), minval=-1.0, maxval=1.0), np.float64)
    cur, cur_lp = tanh_sample(loc_s, ls_s, np.asarray(jax.random.normal(k_cur, (n, B, ACT)), np.float64))
    nxt, nxt_lp = tanh_sample(loc_n, ls_n, np.asarray(jax.random.normal(k_nxt, (n, B, ACT)), np.float64))

    def q_of(a):  # (num_qs, n, B)
        return np.stack([critic(agent.critic.params, obs, a[i]) for i in range(n)], 1)

    q_rand, q_cur, q_nxt = q_of(rand), q_of(cur), q_of(nxt)
    if name == "calql":  # Cal-QL: policy-action values bounded below by the Monte-Carlo return
        q_cur = np.maximum(q_cur, b["mc_returns"])
        q_nxt = np.maximum(q_nxt, b["mc_returns"])
    parts = [q_rand - ACT * math.log(0.5)] + ([] if release else [q_nxt - nxt_lp[None]]) + [q_cur - cur_lp[None]]
    ood = logsumexp(np.concatenate(parts, 1), 1)
    close(info["critic/td_loss"], td)
    close(info["critic/cql_loss"], 2.0 * (ood - qs).mean(1).sum())
    close(loss, td + 2.0 * (ood - qs).mean(1).sum())


def test_cql_defaults_are_the_release_form():
    from d5rl.agents.cql import get_config

    cfg = get_config()
    assert (cfg.cql_n_actions, cfg.cql_next_actions, cfg.cql_max_target_backup) == (4, False, True)


def test_sac_actor_and_temperature_losses_of_cql():
    agent, b = make("cql"), batch()
    key = jax.random.PRNGKey(4)
    loss, info = agent.actor_loss(agent.actor.params, b, key)
    loc, ls = gaussian(agent.actor.params, b["observations"], agent.config, tanh_squash=True)
    a, logp = tanh_sample(loc, ls, np.asarray(jax.random.normal(key, (B, ACT)), np.float64))
    alpha = float(agent.temp.apply_fn({"params": agent.temp.params}))
    q = critic(agent.critic.params, b["observations"], a).min(0)
    close(loss, (alpha * logp - q).mean())
    t_loss, _ = agent.temperature_loss(agent.temp.params, 1.7)
    close(t_loss, alpha * (1.7 - agent.config.target_entropy))


# --- TD3+BC -------------------------------------------------------------------------------------------------
def test_td3bc_losses():
    agent, b = make("td3bc", alpha=2.5, discount=0.9, policy_noise=0.2, noise_clip=0.3), batch()
    key = jax.random.PRNGKey(5)

    noise = np.clip(0.2 * np.asarray(jax.random.normal(key, (B, ACT)), np.float64), -0.3, 0.3)
    a_next = np.clip(deterministic_actor(agent.target_actor_params, b["next_observations"]) + noise, -1, 1)
    target = b["rewards"] + 0.9 * b["masks"] * critic(agent.target_critic_params, b["next_observations"], a_next).min(0)
    qs = critic(agent.critic.params, b["observations"], b["actions"])
    close(agent.critic_loss(agent.critic.params, b, key)[0], ((qs - target) ** 2).mean(1).sum())
    a = deterministic_actor(agent.actor.params, b["observations"])
    q1 = critic(agent.critic.params, b["observations"], a)[0]
    lam = 2.5 / np.abs(q1).mean()
    close(agent.actor_loss(agent.actor.params, b)[0], -lam * q1.mean() + ((a - b["actions"]) ** 2).mean())


def test_td3bc_pixel_form_of_the_release():
    """jaxrl2's pixel TD3+BC as the release runs it: a clipped linear actor, the target action a sample of the
    unit-std Gaussian around it plus noise 0.1 clipped at 0.5, and the actor's Q the mean of both critics."""
    agent = make(
        "td3bc",
        alpha=2.0,
        discount=0.9,
        policy_noise=0.1,
        noise_clip=0.5,
        target_policy_std=1.0,
        actor_output="clip",
        actor_q="mean",
        policy_freq=1,
    )
    b, key = batch(), jax.random.PRNGKey(6)

    def actor(params, obs):  # the linear head, clipped (no tanh)
        p = P(params)
        h = mlp(p["MLP_0"], obs.astype(np.float64), len(p["MLP_0"]), activate_final=True)
        return np.clip(h @ p["Dense_0"]["kernel"] + p["Dense_0"]["bias"], -1, 1)

    gauss = np.asarray(jax.random.normal(jax.random.fold_in(key, 1), (B, ACT)), np.float64)
    noise = np.clip(0.1 * np.asarray(jax.random.normal(key, (B, ACT)), np.float64), -0.5, 0.5)
    a_next = np.clip(actor(agent.target_actor_params, b["next_observations"]) + gauss + noise, -1, 1)
    target = b["rewards"] + 0.9 * b["masks"] * critic(agent.target_critic_params, b["next_observations"], a_next).min(0)
    qs = critic(agent.critic.params, b["observations"], b["actions"])
    close(agent.critic_loss(agent.critic.params, b, key)[0], ((qs - target) ** 2).mean(1).sum())
    a = actor(agent.actor.params, b["observations"])
    q = critic(agent.critic.params, b["observations"], a).mean(0)
    lam = 2.0 / np.abs(q).mean()
    close(agent.actor_loss(agent.actor.params, b)[0], -lam * q.mean() + ((a - b["actions"]) ** 2).mean())
    np.testing.assert_allclose(np.asarray(agent.eval_actions(b["observations"])), a, rtol=1e-5, atol=1e-6)


def test_td3bc_pixel_settings_are_the_release_form():
    from d5rl.settings import resolve

    for task in ("kitchen-standard-mixed-v0", "wx-sorting-v0"):
        c = resolve("td3bc", task).agent
        assert (c.actor_output, c.target_policy_std, c.policy_noise, c.noise_clip, c.policy_freq, c.actor_q) == (
            "clip",
            1.0,
            0.1,
            0.5,
            1,
            "mean",
        ), task
    c = resolve("td3bc", "kitchen-standard-mixed-state-v0").agent  # the TD3+BC authors' form for states
    assert (c.actor_output, c.target_policy_std, c.policy_noise, c.policy_freq, c.actor_q) == (
        "tanh",
        0.0,
        0.2,
        2,
        "first",
    )


# --- ReBRAC ------------------------------------------------------------------------------------------------
def test_rebrac_losses_penalize_both_sides():
    agent = make("rebrac", actor_bc_coef=0.3, critic_bc_coef=0.7, discount=0.9, policy_noise=0.2, noise_clip=0.3)
    b, key = batch(), jax.random.PRNGKey(8)
    b["next_actions"] = np.random.default_rng(3).uniform(-0.9, 0.9, (B, ACT)).astype(np.float32)

    noise = np.clip(0.2 * np.asarray(jax.random.normal(key, (B, ACT)), np.float64), -0.3, 0.3)
    a_next = np.clip(deterministic_actor(agent.target_actor_params, b["next_observations"]) + noise, -1, 1)
    penalty = ((a_next - b["next_actions"]) ** 2).sum(-1)
    next_q = critic(agent.target_critic_params, b["next_observations"], a_next, ln=True).min(0)
    target = b["rewards"] + 0.9 * b["masks"] * (next_q - 0.7 * penalty)
    qs = critic(agent.critic.params, b["observations"], b["actions"], ln=True)
    close(agent.critic_loss(agent.critic.params, b, key)[0], ((qs - target) ** 2).mean(1).sum())
    a = deterministic_actor(agent.actor.params, b["observations"])
    q = critic(agent.critic.params, b["observations"], a, ln=True).min(0)
    want = (0.3 * ((a - b["actions"]) ** 2).sum(-1) - q / np.abs(q).mean()).mean()
    close(agent.actor_loss(agent.actor.params, b)[0], want)


# --- FQL ----------------------------------------------------------------------------------------------------
def test_fql_losses():
    agent = make("fql", actor_hidden_dims=(8, 8), critic_hidden_dims=(8, 8), alpha=3.0, flow_steps=4, discount=0.9)
    b = batch()

    def field(params, obs, x, t=None):
        p = P(params)
        parts = [obs, x] + ([t] if t is not None else [])
        h = mlp(p["MLP_0"], np.concatenate(parts, -1).astype(np.float64), len(p["MLP_0"]), activate_final=True)
        return h @ p["Dense_0"]["kernel"] + p["Dense_0"]["bias"]

    # critic: r + γ·mask·mean of the two target critics at a' = clip(μ(s', z'))
    key = jax.random.PRNGKey(9)
    z = np.asarray(jax.random.normal(key, (B, ACT)), np.float64)
    a_next = np.clip(field(agent.actor.params, b["next_observations"], z), -1, 1)
    target = b["rewards"] + 0.9 * b["masks"] * critic(
        agent.target_critic_params, b["next_observations"], a_next, ln=True
    ).mean(0)
    qs = critic(agent.critic.params, b["observations"], b["actions"], ln=True)
    close(agent.critic_loss(agent.critic.params, b, key)[0], ((qs - target) ** 2).mean())
    # behaviour flow: flow matching from z to the data's action
    key = jax.random.PRNGKey(10)
    k_z, k_t = jax.random.split(key)
    z = np.asarray(jax.random.normal(k_z, (B, ACT)), np.float64)
    t = np.asarray(jax.random.uniform(k_t, (B, 1)), np.float64)
    pred = field(agent.bc_flow.params, b["observations"], (1 - t) * z + t * b["actions"], t)
    close(agent.bc_flow_loss(agent.bc_flow.params, b, key), ((pred - (b["actions"] - z)) ** 2).mean())
    # one-step policy: α·‖μ(s, z) − Euler(flow)(s, z)‖² − mean_i Q_i(s, clip(μ(s, z)))
    key = jax.random.PRNGKey(11)
    k_z, _ = jax.random.split(key)
    z = np.asarray(jax.random.normal(k_z, (B, ACT)), np.float64)
    x = z.copy()
    for i in range(4):
        x = x + field(agent.bc_flow.params, b["observations"], x, np.full((B, 1), i / 4)) / 4
    mu = field(agent.actor.params, b["observations"], z)
    q = critic(agent.critic.params, b["observations"], np.clip(mu, -1, 1), ln=True).mean(0)
    loss, info = agent.actor_loss(agent.actor.params, b, key)
    close(info["actor/distill_loss"], ((mu - np.clip(x, -1, 1)) ** 2).mean())
    close(loss, 3.0 * ((mu - np.clip(x, -1, 1)) ** 2).mean() - q.mean())


# --- RLPD ---------------------------------------------------------------------------------------------------
# (3, 3): every critic, as for the A1 data agents' (2, 2)
@pytest.mark.parametrize("num_qs, num_min_qs", [(4, 2), (3, 3)])
def test_rlpd_critic_loss_uses_a_random_subset_of_layernorm_critics(num_qs, num_min_qs):
    agent = make("rlpd", num_qs=num_qs, num_min_qs=num_min_qs, discount=0.9, backup_entropy=True)
    b = batch()
    key = jax.random.PRNGKey(6)
    loss, _ = agent.critic_loss(agent.critic.params, b, key)
    k_act, k_sub, _ = jax.random.split(key, 3)
    loc, ls = gaussian(agent.actor.params, b["next_observations"], agent.config, tanh_squash=True)
    a_next, logp = tanh_sample(loc, ls, np.asarray(jax.random.normal(k_act, (B, ACT)), np.float64))
    subset = np.asarray(jax.random.choice(k_sub, num_qs, (num_min_qs,), replace=False))
    target_qs = critic(agent.target_critic_params, b["next_observations"], a_next, ln=True)
    alpha = float(agent.temp.apply_fn({"params": agent.temp.params}))
    target = b["rewards"] + 0.9 * b["masks"] * (target_qs[subset].min(0) - alpha * logp)
    qs = critic(agent.critic.params, b["observations"], b["actions"], ln=True)
    close(loss, ((qs - target) ** 2).mean())


# --- diffusion (DDPM+BC, IDQL) ------------------------------------------------------------------------------
def test_cosine_schedule_and_denoising_loss():
    from d5rl.agents.ddpm_bc import diffusion_loss

    T, s = 5, 0.008
    x = np.arange(T + 1) / T  # Nichol & Dhariwal (2021): ᾱ(t) = f(t) / f(0), f(t) = cos²((t/T + s)/(1 + s) · π/2)
    ac = np.cos((x + s) / (1 + s) * np.pi * 0.5) ** 2
    ac = ac / ac[0]
    betas = np.clip(1 - ac[1:] / ac[:-1], 0, 0.999)
    np.testing.assert_allclose(np.asarray(cosine_beta_schedule(T)), betas, rtol=1e-5)

    w = np.array([[0.5, -1.0], [2.0, 0.3]], np.float32)

    def apply_fn(variables, obs, noisy, t, train, rngs):  # a stand-in noise model: linear in its inputs
        return noisy @ variables["params"]["w"] + 0.1 * t + obs[:, :1]

    b, key = batch(), jax.random.PRNGKey(7)
    loss = diffusion_loss(apply_fn, {"w": jnp.asarray(w)}, b["observations"], b["actions"], key, T)
    k_t, k_noise, _ = jax.random.split(key, 3)
    t = np.asarray(jax.random.randint(k_t, (B,), 0, T))
    noise = np.asarray(jax.random.normal(k_noise, (B, ACT)), np.float64)
    alpha_hat = np.cumprod(1 - betas)[t][:, None]
    noisy = np.sqrt(alpha_hat) * b["actions"] + np.sqrt(1 - alpha_hat) * noise
    eps = noisy @ w + 0.1 * t[:, None] + b["observations"][:, :1]
    close(loss, ((eps - noise) ** 2).sum(-1).mean())
