"""Numerics that do not depend on the CPU: the same dataset bytes on every x86-64 machine.

A generator's floating-point results depend on the CPU through the libraries that pick code by
the instructions the CPU has:

- glibc's libm (``exp``, ``sin``, ``cos``, ``pow``, ``atan2``, ... called by MuJoCo, Python's
  ``math`` and numpy's scalar fallbacks) has FMA variants that round differently in the last bit.
  ``GLIBC_TUNABLES=glibc.cpu.hwcaps=-AVX2,-FMA,-FMA4`` makes every x86-64 CPU take the same
  non-FMA variants. The dynamic loader reads it when a process starts, so it can only be set for
  processes started afterwards (the generation workers), never in a running one.
- numpy's SIMD kernels above its baseline (x86-64-v2): its AVX2 and AVX-512 ``exp``, ``tanh``,
  ``sin``, sums... round differently from the baseline ones. ``NPY_DISABLE_CPU_FEATURES`` lists
  every dispatch target, read when numpy is imported.
- OpenBLAS (``np.linalg.solve``, ``norm``...) picks its kernels by CPU core;
  ``OPENBLAS_CORETYPE=Nehalem`` pins the SSE kernels every x86-64-v2 CPU runs.
- MuJoCo's own code takes no CPU-dependent path: the ``mujoco`` wheel is compiled for AVX without
  FMA and has no ``cpuid`` dispatch (``objdump -d libmujoco.so``: no ``vfmadd``, no ``zmm``, no
  ``cpuid``); its transcendental functions are libm's, pinned above.
- XLA is not on the generation path: the A1 data agents' policies run in numpy
  (:mod:`d5rl.production.a1.policy`).

A process is *portable* when it started with these variables and the marker
``D5RL_NUMERICS=portable``, and numpy and OpenBLAS report the pinned kernels
(:func:`probe`). ``python -m d5rl.numerics --check`` prints what this process has pinned;
``python -m d5rl.numerics --env`` prints the variables as shell ``export`` lines.
"""

from __future__ import annotations

import os
import platform
import sys
from pathlib import Path

from d5rl.errors import D5RLError

NUMERICS = ("native", "portable")  # DatasetSpec.numerics
MARKER = "D5RL_NUMERICS"
LIBM_MASK = ("-AVX2", "-FMA", "-FMA4")  # glibc.cpu.hwcaps entries: the libm variants without FMA
OPENBLAS_CORE = "Nehalem"  # SSE4.2 kernels: every x86-64-v2 CPU (numpy's baseline) runs them


def supported() -> bool:
    """Portable numerics are defined for x86-64 Linux with glibc (the variables above are theirs)."""
    return (
        sys.platform.startswith("linux")
        and platform.machine() in ("x86_64", "AMD64")
        and platform.libc_ver()[0] == "glibc"
    )


def numpy_dispatch_targets() -> list[str]:
    """numpy's SIMD targets above its baseline (all of them, whether or not this CPU has them: a target
    the CPU lacks is off anyway, so one list fits every machine)."""
    from numpy._core._multiarray_umath import __cpu_dispatch__

    return list(__cpu_dispatch__)


def _with_libm_mask(tunables: str) -> str:
    """``GLIBC_TUNABLES`` with the libm mask added to its ``glibc.cpu.hwcaps`` (other tunables kept)."""
    items = [t for t in tunables.split(":") if t]
    for i, item in enumerate(items):
        name, _, value = item.partition("=")
        if name == "glibc.cpu.hwcaps":
            have = [v for v in value.split(",") if v]
            items[i] = f"{name}=" + ",".join(have + [m for m in LIBM_MASK if m not in have])
            return ":".join(items)
    return ":".join([*items, "glibc.cpu.hwcaps=" + ",".join(LIBM_MASK)])


def portable_env(environ=os.environ) -> dict[str, str]:
    """The variables a worker process must start with to compute portably (merged with ``environ``'s)."""
    return {
        "GLIBC_TUNABLES": _with_libm_mask(environ.get("GLIBC_TUNABLES", "")),
        "NPY_DISABLE_CPU_FEATURES": " ".join(numpy_dispatch_targets()),
        "OPENBLAS_CORETYPE": OPENBLAS_CORE,
        MARKER: "portable",
    }


def startup_environ() -> dict[str, str]:
    """The environment this process was started with (what the dynamic loader and numpy saw)."""
    try:
        raw = Path("/proc/self/environ").read_bytes()
    except OSError:
        return dict(os.environ)
    pairs = (item.decode(errors="replace").partition("=") for item in raw.split(b"\0") if item)
    return {k: v for k, _, v in pairs}


def openblas_core() -> str | None:
    """The CPU core whose kernels numpy's OpenBLAS runs (None if numpy links another BLAS)."""
    import ctypes

    import numpy as np

    libs = Path(np.__file__).parent.parent / "numpy.libs"
    for lib in sorted(libs.glob("libscipy_openblas*.so*")):
        handle = ctypes.CDLL(str(lib))
        for name in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename", "openblas_get_corename"):
            fn = getattr(handle, name, None)
            if fn is not None:
                fn.restype = ctypes.c_char_p
                return fn().decode()
    return None


def probe() -> dict[str, tuple[bool, str]]:
    """Per library: (pinned, what this process has)."""
    from numpy._core._multiarray_umath import __cpu_features__

    env = startup_environ()
    hwcaps = next(
        (
            t.partition("=")[2].split(",")
            for t in env.get("GLIBC_TUNABLES", "").split(":")
            if t.startswith("glibc.cpu.hwcaps=")
        ),
        [],
    )
    on = [t for t in numpy_dispatch_targets() if __cpu_features__.get(t)]
    core = openblas_core()
    return {
        "marker": (env.get(MARKER) == "portable", f"{MARKER}={env.get(MARKER, '(unset)')}"),
        "libm": (
            all(m in hwcaps for m in LIBM_MASK),
            "GLIBC_TUNABLES at process start: " + (env.get("GLIBC_TUNABLES") or "(unset)"),
        ),
        "numpy": (not on, "SIMD targets on: " + (", ".join(on) or "none (baseline kernels)")),
        "openblas": (
            core is not None and core.lower() == OPENBLAS_CORE.lower(),
            f"core {core}" if core else "numpy is not linked to OpenBLAS (install numpy's PyPI wheel)",
        ),
    }


def is_portable() -> bool:
    """Whether this process computes with the pinned, CPU-independent kernels."""
    return supported() and all(ok for ok, _ in probe().values())


def current() -> str:
    """``"portable"`` or ``"native"``: the numerics of this process (recorded with each shard it writes)."""
    return "portable" if is_portable() else "native"


def check_mode(numerics: str) -> str:
    if numerics not in NUMERICS:
        raise ValueError(f"numerics must be one of {NUMERICS}, got {numerics!r}")
    return numerics


def require(numerics: str) -> None:
    """In a worker: fail with one line if ``numerics`` is portable and this process is not."""
    if check_mode(numerics) == "portable" and supported() and not is_portable():
        missing = [f"{name} ({detail})" for name, (ok, detail) in probe().items() if not ok]
        raise D5RLError(
            "this worker was asked for portable numerics but is not pinned: " + "; ".join(missing),
            "start it with the variables of `python -m d5rl.numerics --env`",
        )


def worker_env(numerics: str) -> dict[str, str] | None:
    """What worker processes must start with for ``numerics``: None when they need nothing
    (native, or this process is portable already and workers inherit its environment)."""
    if check_mode(numerics) == "native" or not supported() or is_portable():
        return None
    return portable_env()


def machine() -> str:
    """The machine class, as references record it: CPU model, its widest vector extension, libc."""
    model, flags = platform.processor() or platform.machine(), set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and model in ("", platform.processor(), platform.machine()):
                model = value.strip()
            elif key.strip() == "flags":
                flags = set(value.split())
                break
    except OSError:
        pass
    widest = next(
        (name for flag, name in (("avx512f", "AVX-512"), ("avx2", "AVX2"), ("avx", "AVX")) if flag in flags), "SSE"
    )
    libc = "-".join(platform.libc_ver())
    return f"{model} ({platform.machine()}, {widest}), {libc or sys.platform}"


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(prog="python -m d5rl.numerics", description=__doc__.split("\n\n")[0])
    group = ap.add_mutually_exclusive_group(required=True)
    group.add_argument("--check", action="store_true", help="print what this process has pinned")
    group.add_argument("--env", action="store_true", help="print the portable variables as shell export lines")
    args = ap.parse_args(argv)
    if args.env:
        import shlex

        for k, v in portable_env().items():
            print(f"export {k}={shlex.quote(v)}")
        return 0
    print(f"machine: {machine()}")
    if not supported():
        print("portable numerics: not defined on this platform (x86-64 Linux with glibc only)")
        return 1
    for name, (ok, detail) in probe().items():
        print(f"{name:9s} {'pinned' if ok else 'NATIVE'}  {detail}")
    print(f"this process: {current()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
