"""Where and how torch runs for the learner: device, threads, determinism, seeds.

Why in one place: these are process-wide torch settings, and twin trials must be
reproducible (same seed, same calls -> same weights on CPU), so every choice that can
change a number is made here, once, and documented.
"""

from __future__ import annotations

import os
import sys
from typing import Literal

import numpy as np
import torch

from testbed.learning.api import EnsembleImpl

# Independent random streams derived from the learner's seed.
STREAM_INIT = 0
STREAM_SAMPLE = 1
STREAM_AUGMENT = 2


class LearningError(RuntimeError):
    """The learner cannot do what was asked (no CUDA, a checkpoint that does not fit)."""


def derive_seed(seed: int, *keys: int) -> int:
    """A 63-bit seed for the stream ``keys`` of ``seed`` (numpy's SeedSequence hashing, so
    nearby seeds and chunk indices give unrelated streams)."""
    words = [int(seed) & 0xFFFF_FFFF_FFFF_FFFF, *(int(k) for k in keys)]
    state = np.random.SeedSequence(words).generate_state(2, dtype=np.uint32)
    return (int(state[0]) << 31) ^ int(state[1])


def generator(seed: int, *keys: int) -> torch.Generator:
    """A CPU ``torch.Generator`` for one stream; CPU even for a CUDA learner, so the
    sampled indices and augmentations do not depend on the device."""
    return torch.Generator(device="cpu").manual_seed(derive_seed(seed, *keys))


def resolve_device(requested: Literal["auto", "cpu", "cuda"]) -> torch.device:
    """``auto``: CUDA when present, else CPU. ``cuda`` without CUDA is an error."""
    if requested == "cpu":
        return torch.device("cpu")
    if torch.cuda.is_available():
        return torch.device("cuda")
    if requested == "cuda":
        raise LearningError(
            "learning.device = 'cuda' but torch sees no CUDA device; "
            "set learning.device to 'auto' or 'cpu'"
        )
    return torch.device("cpu")


def resolve_impl(impl: EnsembleImpl, device: torch.device) -> Literal["loop", "vmap"]:
    """``auto``: the loop on CPU (measured: benchmarks/bench_training.py, about 3x faster
    than vmap on 2 cores); vmap on CUDA, where fewer and larger kernels usually win (not measured
    here: re-run the benchmark on the GPU machine and adjust this line if it says so)."""
    if impl == "auto":
        return "vmap" if device.type == "cuda" else "loop"
    return impl


def configure_torch(num_threads: int | None = None) -> int:
    """Set torch's intra-op threads and deterministic algorithms; return the thread count.

    Default: every core this process may use. Training runs beside the twin hosts'
    agents and the controller, which are mostly idle while the arms push; the threads
    only hurt when a core is busy AND OpenMP's idle workers spin, so the package sets
    ``OMP_WAIT_POLICY=PASSIVE`` before torch loads (``testbed/learning/__init__.py``).
    Measured, C.U.R.'s step (5 members + safety critic, batch 256) on 2 cores: 1 thread
    2.4-2.7 s; 2 threads 1.45-1.5 s with a free core; with the other core busy 2.9 s
    (PASSIVE) against 7.7 s (spinning: the reason this default used to be half the
    cores). So the thread count follows what is free without being told.
    Deterministic algorithms are warn-only: CPU ops here are deterministic anyway; on
    CUDA it picks deterministic kernels where they exist. Set by :func:`_deterministic`,
    not ``torch.use_deterministic_algorithms``, which imports torch's compiler (inductor
    and dynamo) to set its flag too: 1.5 CPU-s in every process that makes a learner (a
    trial, a protocol, each Ray worker, measured with ``/usr/bin/time``), for a compiler
    the project runs only with ``learning.compile_act`` (which sets the flag first:
    :func:`compiler_deterministic`)."""
    if num_threads is None and os.environ.get("TESTBED_THREADS", "").isdigit():
        num_threads = int(os.environ["TESTBED_THREADS"])  # a Ray trial: its CPUs
    if num_threads is None:
        try:
            cores = len(os.sched_getaffinity(0))
        except AttributeError:  # not Linux
            cores = os.cpu_count() or 1
        num_threads = cores
    num_threads = max(1, int(num_threads))
    if torch.get_num_threads() != num_threads:
        torch.set_num_threads(num_threads)
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    _deterministic()
    return num_threads


def _deterministic() -> None:
    """What ``torch.use_deterministic_algorithms(True, warn_only=True)`` does, without
    importing inductor for its ``deterministic`` flag unless something already has (then
    that flag is set as torch sets it). torch is pinned (pyproject.toml); a torch without
    the private setter takes the public call."""
    setter = getattr(torch._C, "_set_deterministic_algorithms", None)
    if setter is None:
        torch.use_deterministic_algorithms(True, warn_only=True)
        return
    inductor = sys.modules.get("torch._inductor.config")
    if inductor is not None:
        inductor.deterministic = True
    setter(True, warn_only=True)


def compiler_deterministic() -> None:
    """Before ``torch.compile`` (``learning.compile_act``): the compiler's
    ``deterministic`` flag as torch's own deterministic setting says, which
    :func:`_deterministic` left to whoever imports the compiler."""
    import torch._inductor.config as inductor

    inductor.deterministic = torch.are_deterministic_algorithms_enabled()
