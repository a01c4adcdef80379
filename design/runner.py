"""Batch evaluation of candidates: in this process, on a local Dask cluster, or on any
existing cluster.

The client splits the candidates a search asks for into chunks (tasks), skips those the
store already holds, submits the rest and appends each chunk's evaluations to the store as
it completes (:class:`design.store.Store`). A worker keeps one :class:`Evaluator` per
problem for its whole life (:func:`evaluate_chunk`): the preset, the drive limits and the
compiled functions are built once per worker, not per task. A worker lost mid-run loses
nothing: the scheduler gives its tasks to another worker, and what was already received is
on disk. Ctrl-C cancels the outstanding tasks and shuts the cluster down; the evaluations
received so far stay in the store.
"""

from __future__ import annotations

import hashlib
import logging
import math
import os
import re
import signal
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from controllers.progress import Progress
from design.objectives import Evaluation, Evaluator, candidate_key
from design.store import Store
from design.targets import Targets
from toggle.interrupts import signals_held
from toggle.params import ParameterError

#: A scheduler address as ``dask scheduler`` prints it.
ADDRESS = re.compile(r"^(tcp|tls)://[A-Za-z0-9_.\-\[\]:]+:\d{1,5}$")
#: Seconds to wait for a scheduler before calling it unreachable.
CONNECT_TIMEOUT = 10.0
#: Tasks per worker a batch is split into (load balance against per-task overhead).
TASKS_PER_WORKER = 4
#: Most candidates per task (about 0.3 s of work at 17 ms each).
MAX_CHUNK = 16
#: Fewest candidates worth a local cluster: below, its start (3-5 s) is most of the run.
MIN_CLUSTER_WORK = 200


#: The probe of the cores busy now: samples of the runnable tasks, and their spacing (s).
PROBE_SAMPLES, PROBE_INTERVAL = 20, 0.005


def busy_cores(loadavg: Path | str = "/proc/loadavg", average: float | None = None) -> float:
    """Cores other processes keep busy: the larger of the one-minute load average and the
    runnable tasks now (the mean of a 0.1 s probe of /proc/loadavg's count, less this
    process). The load average lags a new CPU hog by a minute; the count alone is one
    instant of a machine whose load comes and goes. ``average``: the load average to take
    (default the machine's)."""
    average = os.getloadavg()[0] if average is None else average
    counts = []
    try:
        for i in range(PROBE_SAMPLES):
            if i:
                time.sleep(PROBE_INTERVAL)
            counts.append(int(Path(loadavg).read_text().split()[3].split("/")[0]) - 1)
    except (OSError, IndexError, ValueError):  # not Linux: the load average alone
        return average
    return max(average, sum(counts) / len(counts))


def default_workers(candidates: int, cores: int | None = None,
                    load: float | None = None) -> int:
    """Local worker processes for the default back-end: one per core this machine has free
    (its cores less those busy, :func:`busy_cores`), or 0 (in this process) when that is
    one core's worth or less, or when the search is too small to pay for the cluster. On the
    loaded two-core machine of docs/design.md the cluster was 2.2 x slower than the process."""
    if candidates < MIN_CLUSTER_WORK:
        return 0
    cores = cores if cores is not None else os.cpu_count() or 1
    load = load if load is not None else busy_cores()
    free = int(cores - load + 0.5)
    return free if free >= 2 else 0

_EVALUATORS: dict[tuple[str, tuple[str, ...]], Evaluator] = {}


class ClusterError(ParameterError):
    """The Dask scheduler cannot be reached (a bad --scheduler: a usage error)."""


def evaluator_for(targets: Targets) -> Evaluator:
    """This process's evaluator of ``targets``, built on first use."""
    key = (targets.digest(), targets.objectives)
    if key not in _EVALUATORS:
        _EVALUATORS[key] = Evaluator(targets)
    return _EVALUATORS[key]


def evaluate_chunk(targets: Targets, vectors: Sequence[Sequence[float]]) -> list[dict]:
    """A Dask task: evaluate candidates on this worker (records, plain data for the wire)."""
    evaluator = evaluator_for(targets)
    return [evaluator(v).as_record() for v in vectors]


def check_address(address: str) -> str:
    """A scheduler address ``tcp://HOST:PORT`` or ClusterError naming the fault."""
    if not ADDRESS.match(address):
        raise ClusterError(f"--scheduler must look like tcp://HOST:PORT, got {address!r}")
    return address


class Runner:
    """Evaluates batches of candidates through a store; a context manager that owns the
    cluster it starts.

    ``scheduler``: the address of an existing Dask scheduler; else ``workers`` local worker
    processes (None: :func:`default_workers` for ``total`` candidates; 0: no Dask, in this
    process). ``progress``: one bar over the whole search (``total`` candidates, those
    found in the store counted as done), with a count and an ETA.
    """

    def __init__(self, targets: Targets, store: Store, *, scheduler: str | None = None,
                 workers: int | None = None, progress: bool = False,
                 connect_timeout: float = CONNECT_TIMEOUT, total: int | None = None) -> None:
        self.targets, self.store, self.progress = targets, store, progress
        self.total = total
        self._bar: Progress | None = None
        self.connect_timeout = connect_timeout
        self.scheduler, self.workers = scheduler, workers
        self.client: Any = None
        self._cluster: Any = None
        self.evaluated = 0  # candidates evaluated by this runner (not found in the store)

    def __enter__(self) -> Runner:
        if self.workers is None and self.scheduler is None:
            self.workers = default_workers(self.total or 0)
        # a bar on a terminal, a line a minute in a log (it was silent there for minutes)
        self._bar = Progress("toggle design", unit="design", total=self.total or 0,
                             enabled=self.progress)
        if self.scheduler is not None:
            self.client = _connect(check_address(self.scheduler), self.connect_timeout)
        elif self.workers != 0:
            from dask.distributed import Client, LocalCluster
            n = self.workers
            # the workers' own log lines (a cancelled task at Ctrl-C) are not the user's news
            # Ctrl-C or SIGTERM while the cluster starts is acted on once it is up (stopped
            # half-way, distributed's cleanup failed with a traceback), and its event loop
            # and worker processes never see the terminal's Ctrl-C: this process closes them
            try:
                with signals_held(signal.SIGINT, signal.SIGTERM):
                    self._cluster = LocalCluster(
                        n_workers=n, threads_per_worker=1, processes=True,
                        dashboard_address=":0", silence_logs=logging.CRITICAL)
                    self.client = Client(self._cluster)
            except BaseException:
                self.__exit__()
                raise
        return self

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.close()
        if self.client is not None:
            self.client.close()
        if self._cluster is not None:
            self._cluster.close()

    @property
    def worker_count(self) -> int:
        if self.client is None:
            return 1
        return max(1, len(self.client.scheduler_info().get("workers", {})))

    def evaluate(self, vectors: Sequence[Sequence[float]]) -> list[Evaluation]:
        """Evaluations of ``vectors`` in their order; new ones computed and stored."""
        digest = self.store.digest
        keys = [candidate_key(digest, v) for v in vectors]
        todo: dict[str, Sequence[float]] = {}
        for k, v in zip(keys, vectors):
            if k not in self.store and k not in todo:
                todo[k] = v
        self._bar.advance(len(vectors) - len(todo))  # found in the record: done
        if todo:
            self._compute(list(todo.values()))
        return [self.store.get(k) for k in keys]

    def _compute(self, vectors: list[Sequence[float]]) -> None:
        if self.client is None:
            evaluator = evaluator_for(self.targets)
            for v in vectors:
                self.store.append([evaluator(v)])
                self._bar.advance()
        else:
            self._on_dask(vectors, self._bar)
        self.evaluated += len(vectors)

    def _on_dask(self, vectors: list[Sequence[float]], bar: Progress) -> None:
        from dask.distributed import as_completed
        size = max(1, min(MAX_CHUNK, math.ceil(
            len(vectors) / (TASKS_PER_WORKER * self.worker_count))))
        chunks = [vectors[i:i + size] for i in range(0, len(vectors), size)]
        targets = self.client.scatter(self.targets, broadcast=True, hash=False)
        futures = [self.client.submit(evaluate_chunk, targets, [list(map(float, v)) for v in c],
                                      key=_task_key(self.store.digest, c), retries=2)
                   for c in chunks]
        try:
            for future in as_completed(futures):
                records = future.result()
                self.store.append(Evaluation.from_record(r) for r in records)
                bar.advance(len(records))
        except BaseException:
            self.client.cancel(futures)
            raise


def _task_key(digest: str, chunk: Sequence[Sequence[float]]) -> str:
    h = hashlib.sha256("".join(candidate_key(digest, v) for v in chunk).encode())
    return f"design-{h.hexdigest()[:24]}"


def _connect(address: str, timeout: float) -> Any:
    from dask.distributed import Client
    try:
        return Client(address, timeout=timeout)
    except (OSError, TimeoutError) as exc:
        why = " ".join(str(exc).split()) or type(exc).__name__
        raise ClusterError(f"cannot reach the Dask scheduler at {address} within "
                           f"{timeout:g} s: {why}") from None
