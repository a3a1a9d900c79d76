"""The ``ray`` executor (``run.executor: ray``): each sequence runs on a Ray actor that builds the pipeline once and
writes its outputs to ``output.dir``, on this machine or on a cluster; Ray retries a sequence whose worker process
dies. Ray is imported only when a run uses it (``pip install -e '.[ray]'``).

Ray's own primitives do the work: one actor class (its pipeline, hence its models, built once per actor; restarted
by Ray when its process dies, ``max_restarts``; the sequence it was running sent again, ``max_task_retries``) and
:class:`ray.util.ActorPool`, which hands the next sequence to whichever actor is free. An error of a sequence
(a bad file, a stage failing) comes back as that sequence's one-line reason and is not retried.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import re
import socket
import time
from typing import Callable

from .cache import Cache
from .errors import EponetError, SpecError
from .inputs import SequenceSource
from .outputs import remove_partials
from .spec import Spec

__all__ = ["run_on_ray", "connect", "await_release", "SequenceWorker", "ray_missing", "address_problem", "RETRIES", "CONNECT_TIMEOUT_S"]

log = logging.getLogger(__name__)

#: A sequence whose worker process dies (killed, out of memory, its node lost) is run again up to this many times on
#: the restarted actor (Ray's ``max_task_retries``; actors restart without limit, ``max_restarts=-1``).
RETRIES = 2

#: Seconds to wait for ``run.address`` to accept a connection before the run stops with one line (exit code 2).
CONNECT_TIMEOUT_S = 10.0

_ADDRESS = re.compile(r"^(ray://)?(\[[0-9a-fA-F:]+\]|[A-Za-z0-9.-]+):(\d{1,5})$")


def ray_missing() -> str | None:
    """The validation line for ``executor: ray`` without Ray installed (nothing is imported), else ``None``."""
    if importlib.util.find_spec("ray") is None:
        return "run.executor: ray is not installed; install eponet's ray extra: pip install -e '.[ray]'"
    return None


def address_problem(address) -> str | None:
    """The validation line for a malformed ``run.address`` (``null``, ``auto``, ``ray://host:port``, ``host:port``)."""
    if address is None or address == "auto":
        return None
    match = _ADDRESS.match(str(address))
    if match is None or not 0 < int(match[3]) < 65536:
        return f"run.address: expected null, 'auto', 'ray://host:port' or 'host:port', got {address!r}"
    return None


def _probe(address: str, shown: str) -> None:
    """Raise :class:`SpecError` (exit code 2) unless ``address`` (``[ray://]host:port``) accepts a TCP connection
    within :data:`CONNECT_TIMEOUT_S`: Ray itself waits minutes for an address that does not answer."""
    match = _ADDRESS.match(address)
    if match is None:
        raise SpecError(f"run.address: {shown} resolves to {address!r}, which is not host:port")
    host, port = match[2].strip("[]"), int(match[3])
    try:
        socket.create_connection((host, port), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        reason = "timed out" if isinstance(exc, socket.timeout) else exc.strerror or exc.__class__.__name__
        raise SpecError(f"run.address: cannot reach the Ray cluster at {shown} ({reason}; waited at most "
                        f"{CONNECT_TIMEOUT_S:g} s)") from None


def connect(address: str | None) -> bool:
    """Join Ray: a Ray already initialised in this process as it is; ``None`` starts a local instance with this
    machine's CPUs; ``auto`` joins the cluster this machine is part of (``ray start``, ``RAY_ADDRESS``); else the
    address (``ray://`` through Ray Client). Returns whether this call connected (and so should disconnect)."""
    import ray

    if ray.is_initialized():
        return False
    options = dict(include_dashboard=False, logging_level=logging.WARNING)
    if address is None:
        ray.init(address="local", **options)
        return True
    target = address
    if address == "auto":
        target = os.environ.get("RAY_ADDRESS") or _auto_address()
        if target is None:
            raise SpecError("run.address: auto found no Ray cluster on this machine (start one with `ray start "
                            "--head`, or give its address)")
    _probe(target, address if address == target else f"{address} ({target})")
    try:
        ray.init(address=address, **options)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise SpecError(f"run.address: cannot join the Ray cluster at {address} ({_first_line(exc)})") from None
    return True


def _auto_address() -> str | None:
    """The address ``ray.init(address='auto')`` would join (the last ``ray start`` on this machine), or ``None``."""
    try:
        from ray._private.services import canonicalize_bootstrap_address  # no public equivalent

        return canonicalize_bootstrap_address("auto")
    except Exception:  # noqa: BLE001 - no cluster found, or another Ray: ray.init reports it
        return None


class SequenceWorker:
    """A Ray actor's state: the spec's pipeline, built once, with torch/OpenCV limited to the CPUs Ray gave it."""

    def __init__(self, spec: Spec, cache_root: str, cache_enabled: bool, cpus: int):
        import ray

        from .progress import set_quiet
        from .workers import limit_threads

        # ``cpus``: the ``num_cpus`` the executor planned this actor with (also what a restarted actor gets again)
        self.threads = max(1, int(cpus))
        limit_threads(self.threads)
        set_quiet(True)
        self.node = ray.util.get_node_ip_address()
        self.problem = None
        try:
            from .pipeline import Pipeline

            self.pipeline = Pipeline(spec, cache=Cache(cache_root, enabled=cache_enabled))
        except EponetError as exc:  # e.g. weights missing on this node: each of its sequences says so
            self.problem = (str(exc), exc.exit_code)
        except Exception as exc:  # noqa: BLE001 - the same, for a failure that is not one of eponet's
            self.problem = (f"the pipeline failed to start on {self.node}: {exc.__class__.__name__}: {exc}", 1)

    def describe(self) -> dict:
        """Where this actor runs: ``node``, ``pid``, ``threads``, and ``problem`` when its pipeline failed to start."""
        return {"node": self.node, "pid": os.getpid(), "threads": self.threads,
                "problem": self.problem[0] if self.problem else None}

    def run(self, source: SequenceSource) -> tuple[str, str, object]:
        """``(name, "ok", run.json entry)`` or ``(name, "error", (one-line reason, exit code))``."""
        if self.problem is not None:
            return source.name, "error", self.problem
        try:
            entry = self.pipeline.run_sequence(source)
        except EponetError as exc:
            return source.name, "error", (str(exc), exc.exit_code)
        except Exception as exc:  # noqa: BLE001 - one line for the run record, like the local workers
            return source.name, "error", (f"{source.name}: {exc.__class__.__name__}: {exc}", 1)
        entry["worker"] = {k: v for k, v in self.describe().items() if k != "problem"}
        return source.name, "ok", entry


def _actor_plan(ray, workers, sequences: int) -> tuple[int, int]:
    """``(actors, CPUs per actor)``: ``workers: auto`` is one actor per free CPU of the cluster (at most one per
    sequence), a number at most that many; the free CPUs are shared out, at most one node's CPUs per actor."""
    free = max(1, int(ray.available_resources().get("CPU", 1)))
    wanted = free if workers == "auto" else int(workers)
    actors = max(1, min(wanted, free, sequences))
    if actors < wanted and wanted <= sequences:
        log.info("run.workers %s: the Ray cluster has %d free CPUs, so %d actors", workers, free, actors)
    largest = max((int(n["Resources"].get("CPU", 0)) for n in ray.nodes() if n.get("Alive")), default=1)
    return actors, max(1, min(free // actors, largest))


def run_on_ray(pipeline, sources: list[SequenceSource], finished: Callable[[str, dict], None],
               failed: Callable[[str, str, int], None]) -> dict:
    """Run ``sources`` on Ray actors; ``finished(name, entry)`` for each sequence done, ``failed(name, reason,
    exit_code)`` for each that failed or whose worker was lost beyond :data:`RETRIES`, in the order they end.
    Returns what ``run.json`` records of it: the actors and the CPUs of each."""
    if not sources:
        return {"actors": 0}
    spec = pipeline.spec
    joined = connect(spec.run.address)
    import ray
    from ray.util import ActorPool

    actors = []
    free_before = ray.available_resources().get("CPU", 0)
    try:
        count, cpus = _actor_plan(ray, spec.run.workers, len(sources))
        actor_class = ray.remote(SequenceWorker).options(num_cpus=cpus, max_restarts=-1, max_task_retries=RETRIES)
        actors = [actor_class.remote(spec, str(pipeline.cache.root), pipeline.cache.enabled, cpus) for _ in range(count)]
        log.info("Ray: %d actors of %d CPU(s) for %d sequences", count, cpus, len(sources))
        pool = ActorPool(actors)
        for source in sources:
            pool.submit(lambda actor, value: actor.run.remote(value), source)
        pending = [source.name for source in sources]
        lost, dead = [], 0
        while pool.has_next() and dead < count:
            try:
                name, status, value = pool.get_next_unordered()
            except ray.exceptions.RayError as exc:  # a worker gone for good: which sequence is known at the end
                log.warning("Ray lost a worker: %s: %s", exc.__class__.__name__, _first_line(exc))
                lost.append(exc.__class__.__name__)
                dead += isinstance(exc, ray.exceptions.ActorDiedError)
                continue
            pending.remove(name)
            if status == "ok":
                finished(name, value)
            else:
                failed(name, *value)
        kinds = ", ".join(sorted(set(lost)))
        for name in pending:
            failed(name, f"{name}: not finished: every Ray actor died ({kinds})" if dead >= count else
                   f"{name}: not finished: its Ray worker died ({kinds}) and {RETRIES} retries did not complete it", 1)
        # every actor is idle now: what the attempts of killed workers left half-written can go (after an
        # interruption, actors may still be writing: the next run removes their folders)
        remove_partials(spec.output.dir)
        return {"actors": count, "cpus_per_actor": cpus, "address": spec.run.address, "retries": RETRIES}
    finally:
        for actor in actors:
            ray.kill(actor)
        if actors and not joined:
            await_release(ray, free_before)
        if joined:
            ray.shutdown()


def await_release(ray, free: float, timeout_s: float = 10.0) -> None:
    """Wait (at most ``timeout_s``) until the killed actors' CPUs are free again: ``ray.kill`` returns before Ray
    releases them, and a run that follows at once in the same Ray would plan its actors on fewer CPUs."""
    deadline = time.monotonic() + timeout_s
    while ray.available_resources().get("CPU", 0) < free and time.monotonic() < deadline:
        time.sleep(0.05)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else exc.__class__.__name__
