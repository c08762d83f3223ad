"""Many processes: ``jax.distributed`` set-up from the command line, the writing process,
broadcasts, barriers and gathers.
"""

from __future__ import annotations

import argparse
import socket

import jax
import numpy as np
from jax.experimental import multihost_utils

# ---------------------------------------------------------------- many processes


def initialize(
    coordinator: str | None = None, num_processes: int | None = None, process_id: int | None = None
) -> None:
    """Start JAX's multi-process runtime (one process per host): ``jax.distributed.initialize``.

    Without arguments JAX detects the cluster (SLURM, Open MPI, cloud TPU); otherwise give
    the coordinator's ``host:port`` (process 0's host), the process count and this process's
    index. On CPUs the cross-process collectives use gloo. Call it before any other JAX
    call (the CLIs do it first thing with ``--coordinator``/``--num-processes``/
    ``--process-id``, or ``--distributed`` for auto-detection).
    """
    if jax.config.jax_platforms in (None, "", "cpu") or "cpu" in str(jax.config.jax_platforms):
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator, num_processes, process_id)


def add_cli_args(parser: argparse.ArgumentParser) -> None:
    """The multi-host flags shared by the experiment CLIs."""
    g = parser.add_argument_group(
        "many hosts (one process per host; see slotv_jax.training.parallel)"
    )
    g.add_argument("--distributed", action="store_true",
                   help="jax.distributed.initialize() with cluster auto-detection")  # fmt: skip
    g.add_argument("--coordinator", help="host:port of process 0 (with the two flags below)")
    g.add_argument("--num-processes", type=int)
    g.add_argument("--process-id", type=int)


def check_coordinator(coordinator: str) -> None:
    """``HOST:PORT`` of process 0, with a host this machine can resolve: else a ValueError
    naming ``--coordinator`` at once (JAX would wait its 5-minute connection timeout and
    abort the process with a C++ stack trace)."""
    host, sep, port = coordinator.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"--coordinator {coordinator}: expected HOST:PORT, e.g. 10.0.0.1:12355")
    try:
        socket.getaddrinfo(host.strip("[]"), int(port))
    except OSError as e:
        raise ValueError(
            f"--coordinator {coordinator}: cannot resolve host {host!r} ({e.strerror}); give "
            "process 0's host name or address as this machine knows it"
        ) from None


def init_from_args(args: argparse.Namespace) -> None:
    """Call :func:`initialize` if the parsed :func:`add_cli_args` flags ask for it."""
    manual = (args.coordinator, args.num_processes, args.process_id)
    if any(v is not None for v in manual):
        if any(v is None for v in manual):
            raise ValueError(
                "--coordinator, --num-processes, --process-id: expected all three or none"
            )
        if not 0 <= args.process_id < args.num_processes:
            raise ValueError(
                f"--process-id: expected 0 <= id < {args.num_processes}, got {args.process_id}"
            )
        check_coordinator(args.coordinator)
        initialize(*manual)
    elif args.distributed:
        initialize()


def is_writer() -> bool:
    """Whether this process writes the results (process 0)."""
    return jax.process_index() == 0


def broadcast(x: np.ndarray) -> np.ndarray:
    """Process 0's value of a host array of the same shape on every process."""
    if jax.process_count() == 1:
        return np.asarray(x)
    return np.asarray(multihost_utils.broadcast_one_to_all(np.asarray(x)))


def barrier(name: str) -> None:
    """Wait until every process has reached the barrier ``name``."""
    if jax.process_count() > 1:
        multihost_utils.sync_global_devices(name)


def fetch(x: jax.Array) -> np.ndarray:
    """The whole value of a (possibly multi-host) array on every process, as NumPy."""
    if jax.process_count() == 1 or x.is_fully_addressable:
        return np.asarray(x)
    return np.asarray(multihost_utils.process_allgather(x, tiled=True))
