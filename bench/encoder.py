"""Where pixel agents spend their time on CPU: the IMPALA encoder, layer by layer, JAX vs. PyTorch.

    python bench/encoder.py                  # batch 64, two 64×64 cameras × 3 stacked frames
    python bench/encoder.py --batch 32 --seconds 1

For every distinct convolution of d5rl's IMPALA encoder it times the forward pass, the gradient
with respect to the input (dx) and the gradient with respect to the weights (dw), each on its own:
JAX as ``jax.jit`` of ``lax.conv_general_dilated`` (and its VJP) with the XLA flags ``import d5rl``
sets; PyTorch eager as ``F.conv2d`` and ``aten.convolution_backward`` with an ``output_mask``, in
channels-last memory format (what bench/agents.py's reference uses; oneDNN's fastest CPU path)
and, for the whole encoder only, in the default contiguous NCHW format.  Then the whole encoder:
forward + gradient of all parameters.  The ``ratio`` column is JAX's speed over PyTorch
channels-last (above 1: JAX is faster).  Numbers are medians of alternating repeats.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys

import numpy as np

CAMS, STACK, PIX = 2, 3, 64


def timer(fn, seconds: float) -> float:
    """Seconds per call of ``fn`` (which must block until its result is ready), after one warm-up call."""
    from agents import rate  # bench/agents.py

    fn()

    def run(n: int) -> int:
        for _ in range(n):
            fn()
        return n

    return 1.0 / rate(run, seconds)


def conv_shapes(channels, in_ch: int, size: int):
    """(spatial size, in channels, out channels, how many in the encoder) for each distinct 3×3 conv."""
    out = []
    for ch in channels:
        out.append((size, in_ch, ch, 1))  # the stack's first conv, before the max-pool
        size = (size + 1) // 2
        out.append((size, ch, ch, 4))  # two residual blocks of two convs
        in_ch = ch
    return out


def jax_layer(batch, size, cin, cout, rng):
    import jax
    import jax.numpy as jnp

    def conv(x, w):
        return jax.lax.conv_general_dilated(x, w, (1, 1), "SAME", dimension_numbers=("NHWC", "HWIO", "NHWC"))

    x = jnp.asarray(rng.random((batch, size, size, cin), dtype=np.float32))
    w = jnp.asarray(rng.standard_normal((3, 3, cin, cout), dtype=np.float32) * 0.1)
    dy = jnp.asarray(rng.standard_normal((batch, size, size, cout), dtype=np.float32))
    fwd = jax.jit(conv)
    dx = jax.jit(lambda x, w, dy: jax.vjp(lambda x: conv(x, w), x)[1](dy)[0])
    dw = jax.jit(lambda x, w, dy: jax.vjp(lambda w: conv(x, w), w)[1](dy)[0])
    return {
        "fwd": lambda: fwd(x, w).block_until_ready(),
        "dx": lambda: dx(x, w, dy).block_until_ready(),
        "dw": lambda: dw(x, w, dy).block_until_ready(),
    }


def torch_layer(batch, size, cin, cout, rng):
    import torch
    import torch.nn.functional as F

    cl = torch.channels_last
    x = torch.from_numpy(rng.random((batch, cin, size, size), dtype=np.float32)).contiguous(memory_format=cl)
    w = torch.from_numpy(rng.standard_normal((cout, cin, 3, 3), dtype=np.float32) * 0.1).contiguous(memory_format=cl)
    dy = torch.from_numpy(rng.standard_normal((batch, cout, size, size), dtype=np.float32)).contiguous(memory_format=cl)

    def backward(mask):
        return lambda: torch.ops.aten.convolution_backward(
            dy, x, w, [cout], [1, 1], [1, 1], [1, 1], False, [0, 0], 1, mask
        )

    return {
        "fwd": lambda: F.conv2d(x, w, padding=1),
        "dx": backward([True, False, False]),
        "dw": backward([False, True, True]),
    }


def jax_encoder(batch, rng):
    import jax
    import jax.numpy as jnp

    from d5rl.agents.encoders import ImpalaEncoder

    x = jnp.asarray(rng.random((batch, PIX, PIX, 3 * STACK * CAMS), dtype=np.float32))
    enc = ImpalaEncoder()
    params = enc.init(jax.random.PRNGKey(0), x[:1])
    grad = jax.jit(jax.grad(lambda p, x: jnp.sum(enc.apply(p, x) ** 2)))
    return lambda: jax.block_until_ready(grad(params, x))


def torch_encoder(batch, rng, channels_last: bool):
    import torch
    from torch_reference import torch_impala  # the reference encoder bench/agents.py times

    net = torch_impala()(3 * STACK * CAMS)
    x = torch.from_numpy(rng.random((batch, 3 * STACK * CAMS, PIX, PIX), dtype=np.float32))
    if channels_last:
        net, x = net.to(memory_format=torch.channels_last), x.contiguous(memory_format=torch.channels_last)

    def step():
        net.zero_grad(set_to_none=True)
        (net(x) ** 2).sum().backward()

    return step


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--batch", type=int, default=64)
    p.add_argument("--seconds", type=float, default=2.0, help="per measurement")
    p.add_argument("--repeats", type=int, default=3, help="alternating JAX / torch repeats (median)")
    p.add_argument("--torch-threads", type=int, default=0, help="torch intra-op threads; 0 = all CPUs")
    args = p.parse_args(argv)

    import jax

    import d5rl  # noqa: F401  (sets d5rl's XLA flags before JAX starts)

    try:
        import torch
    except ImportError:
        print("bench/encoder.py compares against PyTorch: pip install torch", file=sys.stderr)
        return 2
    torch.set_num_threads(args.torch_threads or os.cpu_count() or 1)
    rng = np.random.default_rng(0)

    def med(fns):
        times = [[] for _ in fns]
        for _ in range(args.repeats):
            for t, fn in zip(times, fns):
                t.append(timer(fn, args.seconds))
        return [statistics.median(t) * 1e3 for t in times]

    print(
        f"# {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, jax {jax.__version__}, "
        f"torch {torch.__version__} ({torch.get_num_threads()} threads), batch {args.batch}, ms per call"
    )
    print(f"{'conv':22s} {'n':>2s} {'pass':4s} {'jax':>8s} {'torch':>8s} {'ratio':>6s}")
    total_j = total_t = 0.0
    first = True
    from d5rl.agents.encoders import ImpalaEncoder

    for size, cin, cout, n in conv_shapes(ImpalaEncoder.channels, 3 * STACK * CAMS, PIX):
        jl, tl = jax_layer(args.batch, size, cin, cout, rng), torch_layer(args.batch, size, cin, cout, rng)
        for name in ("fwd", "dx", "dw"):
            if name == "dx" and first:
                continue  # the input image needs no gradient
            j, t = med([jl[name], tl[name]])
            total_j, total_t = total_j + n * j, total_t + n * t
            print(
                f"{size:3d}x{size:<3d} {cin:2d}->{cout:<2d} 3x3    {n:2d} {name:4s} {j:8.2f} {t:8.2f} {t / j:6.2f}",
                flush=True,
            )
        first = False
    print(f"{'all convolutions':27s} {'':4s} {total_j:8.1f} {total_t:8.1f} {total_t / total_j:6.2f}")
    j, t, t_nchw = med(
        [jax_encoder(args.batch, rng), torch_encoder(args.batch, rng, True), torch_encoder(args.batch, rng, False)]
    )
    print(f"{'encoder fwd+grad':27s} {'':4s} {j:8.1f} {t:8.1f} {t / j:6.2f}")
    print(f"{'  vs torch NCHW':27s} {'':4s} {j:8.1f} {t_nchw:8.1f} {t_nchw / j:6.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
