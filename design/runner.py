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
#: A worker's rate over this process's own on a core of its own: what the client and the
#: scheduler take (benchmarks/bench_design.py: two workers 1.66 x the process idle, one
#: worker 0.88 x beside a CPU hog). And the gain over the process a cluster must promise.
CLUSTER_EFFICIENCY, CLUSTER_MARGIN = 0.85, 1.05


#: Dask's defaults for a worker that cost a search's tasks CPU (measured on the duty
#: planning, 1.6 s of CPU in this process: 2.1-2.4 s on a default worker, 1.7-1.8 s on
#: ours): the statistical profiler walks the task thread's stack every 10 ms under the GIL,
#: and MALLOC_TRIM_THRESHOLD_=65536 hands freed memory back to the system at once, so
#: CasADi's and IPOPT's allocations fault their pages in again (7x the page faults, 5x the
#: system time). A search's workers live as long as the search: neither is worth it.
WORKER_CONFIG = {"distributed.worker.profile.enabled": False,
                 "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}

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
    """Local worker processes for the default back-end, by the rate each back-end can expect
    under the kernel's fair share of the cores (each of n runnable processes on c cores gets
    min(1, c / n) of a core) beside the ``load`` cores other processes keep busy
    (:func:`busy_cores`): the process evaluates at min(1, c / (load + 1)), w workers at
    :data:`CLUSTER_EFFICIENCY` w min(1, c / (load + w)). The workers are the free cores, at
    least two; the cluster where its rate beats the process's by :data:`CLUSTER_MARGIN`,
    else 0 (in this process), as for a search too small to pay for the cluster's start."""
    if candidates < MIN_CLUSTER_WORK:
        return 0
    cores = cores if cores is not None else os.cpu_count() or 1
    load = max(0.0, load if load is not None else busy_cores())
    workers = min(cores, max(2, int(cores - load + 0.5)))
    alone = min(1.0, cores / (load + 1))
    cluster = CLUSTER_EFFICIENCY * workers * min(1.0, cores / (load + workers))
    return workers if cluster > CLUSTER_MARGIN * alone else 0


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


def duty_chunk(targets: Targets, records: Sequence[dict]) -> list[dict]:
    """A Dask task: the evaluations with their planned duty (:meth:`Evaluator.with_duty`)."""
    evaluator = evaluator_for(targets)
    return [evaluator.with_duty(Evaluation.from_record(r)).as_record() for r in records]


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
            import dask
            from dask.distributed import Client, LocalCluster
            n = self.workers
            # the workers' own log lines (a cancelled task at Ctrl-C) are not the user's news
            # Ctrl-C or SIGTERM while the cluster starts is acted on once it is up (stopped
            # half-way, distributed's cleanup failed with a traceback), and its event loop
            # and worker processes never see the terminal's Ctrl-C: this process closes them
            self._bar.doing(f"starting {n} worker processes")  # named on a pipe's lines
            try:
                with signals_held(signal.SIGINT, signal.SIGTERM), dask.config.set(WORKER_CONFIG):
                    self._cluster = LocalCluster(
                        n_workers=n, threads_per_worker=1, processes=True,
                        dashboard_address=":0", silence_logs=logging.CRITICAL)
                    self.client = Client(self._cluster)
            except BaseException:
                self.__exit__()
                raise
            self._bar.doing(None)
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

    def with_duty(self, evaluations: Sequence[Evaluation]) -> list[Evaluation]:
        """The feasible ``evaluations`` with their closing stroke's planned duty
        (:meth:`Evaluator.with_duty`, about 1.4 s each): those without it planned on this
        back-end, with a bar of their own, and recorded (:meth:`Store.supersede`)."""
        todo = [e for e in evaluations if "close_rms_torque" not in
                (self.store.get(e.key) if e.key in self.store else e).metrics]
        if todo:
            bar = Progress("toggle design: planning the front", unit="design",
                           total=len(todo), enabled=self.progress)
            try:
                if self.client is None:
                    evaluator = evaluator_for(self.targets)
                    for e in todo:
                        self.store.supersede([evaluator.with_duty(e)])
                        bar.advance()
                else:
                    self._on_dask(duty_chunk, [e.as_record() for e in todo], 1, bar,
                                  self.store.supersede)
            finally:
                bar.close()
        return [self.store.get(e.key) if e.key in self.store else e for e in evaluations]

    def _compute(self, vectors: list[Sequence[float]]) -> None:
        if self.client is None:
            evaluator = evaluator_for(self.targets)
            for v in vectors:
                self.store.append([evaluator(v)])
                self._bar.advance()
        else:
            size = max(1, min(MAX_CHUNK, math.ceil(
                len(vectors) / (TASKS_PER_WORKER * self.worker_count))))
            self._on_dask(evaluate_chunk, [list(map(float, v)) for v in vectors], size,
                          self._bar, self.store.append)
        self.evaluated += len(vectors)

    def _on_dask(self, task: Any, items: list[Any], size: int, bar: Progress,
                 record: Any) -> None:
        """``task(targets, chunk)`` on the cluster for chunks of ``size`` items; each
        chunk's evaluations handed to ``record`` as it completes."""
        from dask.distributed import as_completed
        chunks = [items[i:i + size] for i in range(0, len(items), size)]
        targets = self.client.scatter(self.targets, broadcast=True, hash=False)
        futures = [self.client.submit(task, targets, c, retries=2,
                                      key=_task_key(task.__name__, self.store.digest,
                                                    c))
                   for c in chunks]
        try:
            for future in as_completed(futures):
                records = future.result()
                record(Evaluation.from_record(r) for r in records)
                bar.advance(len(records))
        except BaseException:
            self.client.cancel(futures)
            raise


def _task_key(name: str, digest: str, chunk: Sequence[Any]) -> str:
    h = hashlib.sha256(f"{name}{digest}{chunk!r}".encode())
    return f"design-{h.hexdigest()[:24]}"


def _connect(address: str, timeout: float) -> Any:
    from dask.distributed import Client
    try:
        return Client(address, timeout=timeout)
    except (OSError, TimeoutError) as exc:
        why = " ".join(str(exc).split()) or type(exc).__name__
        raise ClusterError(f"cannot reach the Dask scheduler at {address} within "
                           f"{timeout:g} s: {why}") from None
