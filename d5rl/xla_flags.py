"""XLA flags d5rl sets for itself, before JAX starts its CPU client.

Flags go into ``XLA_FLAGS``, appended to what is there; a flag the user already set
(by name) is left as the user set it.  XLA reads the variable once, when the first
computation runs, so these take effect only if nothing has used JAX before.
"""

from __future__ import annotations

import os
from importlib import metadata

# On XLA:CPU, convolutions and their gradients run on Eigen instead of YNNPACK (the default in
# jaxlib 0.10); dot products and reductions stay on YNNPACK, so programs without convolutions
# compile as before. Measured on a 2-core x86 CPU, batch 64: the IMPALA encoder's forward+backward
# ~290 -> ~230 ms; bench/agents.py pixel agents 0.9-1.5x the updates/s (1.3x for most).
# The flag is experimental: it is set only for the jaxlib versions it was measured on (an unknown
# flag makes XLA abort).
CONV_ON_EIGEN = "--xla_cpu_experimental_ynn_fusion_type=LIBRARY_FUSION_TYPE_INDIVIDUAL_DOT,LIBRARY_FUSION_TYPE_REDUCE"
CONV_ON_EIGEN_JAXLIB = ((0, 10),)

# One compute thread per process, for K worker processes on K cores.
SINGLE_THREAD = ("--xla_cpu_multi_thread_eigen=false", "intra_op_parallelism_threads=1")


def add_xla_flags(*flags: str, environ=os.environ) -> None:
    """Append each ``--name=value`` to ``XLA_FLAGS`` unless a flag of that name is already there."""
    current = environ.get("XLA_FLAGS", "")
    names = {f.split("=", 1)[0].lstrip("-") for f in current.split()}
    new = [f for f in flags if f.split("=", 1)[0].lstrip("-") not in names]
    if new:
        environ["XLA_FLAGS"] = " ".join([current, *new]).strip()


def jaxlib_version() -> tuple[int, int] | None:
    try:
        major, minor = metadata.version("jaxlib").split(".")[:2]
        return int(major), int(minor)
    except (metadata.PackageNotFoundError, ValueError):
        return None


def configure_default_flags(environ=os.environ) -> None:
    """The flags every d5rl process gets (called on ``import d5rl``)."""
    if jaxlib_version() in CONV_ON_EIGEN_JAXLIB:
        add_xla_flags(CONV_ON_EIGEN, environ=environ)
