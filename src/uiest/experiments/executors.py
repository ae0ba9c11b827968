"""Where sweep tasks run: in this process, in a pool of local processes, or on a Dask cluster.

Each executor yields ``(task, rows, why)`` as tasks finish: ``rows`` is the task's frame, or
None when it could not be computed here (``why`` says why; the task is left for the next run).

The process pool submits tasks lazily (twice as many as workers at a time), so an interruption
(Ctrl-C, an exception in the caller) cancels what has not started and ends the workers at once.
A worker that dies (a crash in compiled code, the OOM killer) breaks the pool: the tasks that
were running are then run again one at a time, each in a fresh single-worker pool; a task that
kills its worker on its own gets a row recording it (so resumes do not retry it forever), the
others complete normally, and the rest of the sweep goes on. Workers end themselves when their
parent dies.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import sys
import threading
import time
import warnings
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from multiprocessing.process import BaseProcess
from typing import TYPE_CHECKING, Any, TypeAlias

from uiest.errors import OptionError
from uiest.experiments.sweep_design import Task

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["processes", "results", "single_threaded_children", "spawn_pool", "stop_pool"]

Outcome: TypeAlias = "tuple[Task, pd.DataFrame | None, str]"
"""A task, its rows (None when it could not be computed here) and why not ('' otherwise)."""

WORKER_DIED = (
    "WorkerDied: the worker process died while running this task on its own (a crash in compiled code or a "
    "kill); recorded so that resumes do not retry it, rerun with retry_failed to try again"
)


def died_rows(task: Task) -> pd.DataFrame:
    """The row recording a task that kills its worker."""
    import pandas as pd

    return pd.DataFrame([{"key": task.key, **dict(task.params), "case": task.case, "run": task.run,
                          "solver": task.solver, "estimator": "", "error": WORKER_DIED}])  # fmt: skip


def serial(tasks: list[Task], run: Callable[[Task], pd.DataFrame]) -> Iterator[Outcome]:
    """One task after the other in this process; a task that raises is not computed (as in a worker)."""
    for task in tasks:
        try:
            rows = run(task)
        except Exception as exc:  # nothing stored: the task is left for the next run
            yield task, None, f"{type(exc).__name__}: {exc}"
        else:
            yield task, rows, ""


@contextlib.contextmanager
def single_threaded_children() -> Iterator[None]:
    """One BLAS/OpenMP thread in spawned worker processes (they inherit the environment at spawn)."""
    names = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
    previous = {name: os.environ.get(name) for name in names}
    for name in names:
        os.environ.setdefault(name, "1")
    try:
        yield
    finally:
        for name, value in previous.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def _exit_with_parent(parent: int) -> None:
    """Worker initializer: a daemon thread ends the worker once its parent process is gone."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def _plain_warnings() -> None:
    """Worker initializer: warnings as one ``warning: <message>`` line on stderr, each message once per worker.

    A worker's tasks repeat the same warnings (a scale warning per estimator built); the parent's CLI shows its
    own warnings as such lines, and a worker's would otherwise print Python's source lines, once per task.
    """
    shown: set[str] = set()

    def show(message: Warning | str, category: type[Warning], filename: str, lineno: int, file: Any = None,
             line: str | None = None) -> None:  # fmt: skip
        text = str(message)
        if text not in shown:
            shown.add(text)
            sys.stderr.write(f"warning: {text}\n")

    warnings.showwarning = show


def _worker_init(parent: int) -> None:
    """Worker initializer: :func:`_exit_with_parent`, :func:`_plain_warnings`, and Ctrl-C left to the parent.

    A Ctrl-C reaches the whole process group; the parent ends its workers (:func:`stop_pool`), so a worker
    ignores SIGINT instead of printing a KeyboardInterrupt traceback for the task it was running.
    """
    _exit_with_parent(parent)
    _plain_warnings()
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def spawn_pool(width: int) -> ProcessPoolExecutor:
    """A pool of ``width`` spawned processes that end themselves when this process is gone (warnings as plain lines)."""
    return ProcessPoolExecutor(max_workers=width, mp_context=get_context("spawn"), initializer=_worker_init,
                               initargs=(os.getpid(),))  # fmt: skip


SCHEDULER_TIMEOUT = 10.0
"""Seconds the Dask scheduler (at the address given, or the local cluster's) has to answer before the sweep stops with
an OptionError."""

STOP_GRACE = 10.0
"""Seconds abandoned workers get to end after SIGTERM before they are killed."""


def _reaped_elsewhere(process: BaseProcess) -> None:
    """Record a worker that another waiter of this process reaped as killed.

    CPython's pool (3.11) polls each worker with ``waitpid`` until it has reaped it. A worker
    that someone else reaped (``waitpid`` then fails with ECHILD) stays "alive" for it forever:
    its manager thread spins at 100 % CPU sending stop sentinels into a full call queue, and
    ``shutdown(wait=True)`` and the interpreter's exit hang. Such a worker's process is gone
    (while an unreaped one, even a zombie, still exists).
    """
    popen = getattr(process, "_popen", None)
    if popen is None or popen.returncode is not None:
        return
    try:
        os.kill(popen.pid, 0)
    except ProcessLookupError:
        popen.returncode = -signal.SIGKILL
    except OSError:  # it exists (another user's process: cannot be ours)
        pass


def stop_pool(pool: ProcessPoolExecutor, *, abandon: bool) -> None:
    """Shut ``pool`` down and wait for it; ``abandon``: cancel what has not started and end the running workers now.

    Abandoned workers get :data:`STOP_GRACE` seconds after SIGTERM, then SIGKILL. While waiting,
    workers reaped elsewhere are recorded as killed (see :func:`_reaped_elsewhere`), so that a
    broken pool cannot hang its caller or the interpreter's exit.
    """
    workers = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=abandon)
    if abandon:
        for process in workers:
            with contextlib.suppress(Exception):
                process.terminate()
    deadline = time.monotonic() + STOP_GRACE
    while manager is not None and manager.is_alive():
        manager.join(0.05)
        for process in workers:
            _reaped_elsewhere(process)
        if abandon and time.monotonic() > deadline:
            for process in workers:
                with contextlib.suppress(Exception):
                    process.kill()
            deadline = math.inf


def processes(tasks: list[Task], run: Callable[[Task], pd.DataFrame], workers: int | None) -> Iterator[Outcome]:
    """Tasks in a pool of spawned processes (see the module docstring for crashes and interruptions)."""
    width = workers or os.cpu_count() or 1
    pending, suspects = deque(tasks), deque[Task]()
    with single_threaded_children():
        while pending or suspects:
            if pending:
                yield from _until_broken(pending, suspects, run, width)
            while suspects:
                yield from _alone(suspects.popleft(), run)


def _until_broken(
    pending: deque[Task], suspects: deque[Task], run: Callable[[Task], pd.DataFrame], width: int
) -> Iterator[Outcome]:
    """Run ``pending`` in one pool until it is done or a worker dies (the running tasks go to ``suspects``)."""
    pool = spawn_pool(width)
    in_flight: dict[Future[pd.DataFrame], Task] = {}
    finished = False
    try:
        broken = False
        while not broken and (pending or in_flight):
            while pending and len(in_flight) < 2 * width:
                try:
                    future = pool.submit(run, pending[0])
                except BrokenProcessPool:  # an idle worker died: a fresh pool takes over
                    break
                in_flight[future] = pending.popleft()
            if not in_flight:
                break
            done, _ = wait(in_flight, return_when=FIRST_COMPLETED)
            for future in done:
                task = in_flight.pop(future)
                try:
                    rows = future.result()
                except BrokenProcessPool:
                    suspects.append(task)
                    broken = True
                except Exception as exc:  # nothing stored: the task is left for the next run
                    yield task, None, f"{type(exc).__name__}: {exc}"
                else:
                    yield task, rows, ""
        suspects.extend(in_flight.values())
        in_flight.clear()
        finished = True
    finally:
        stop_pool(pool, abandon=not finished)


def _alone(task: Task, run: Callable[[Task], pd.DataFrame]) -> Iterator[Outcome]:
    """Run a suspect in a fresh single-worker pool: a death now is the task's own."""
    pool = spawn_pool(1)
    finished = False
    try:
        try:
            outcome: Outcome = (task, pool.submit(run, task).result(), "")
        except BrokenProcessPool:
            outcome = (task, died_rows(task), "")
        except Exception as exc:
            outcome = (task, None, f"{type(exc).__name__}: {exc}")
        finished = True
    finally:
        stop_pool(pool, abandon=not finished)
    yield outcome


def dask(
    tasks: list[Task], run: Callable[[Task], pd.DataFrame], workers: int | None, scheduler: str
) -> Iterator[Outcome]:
    """Tasks on a Dask cluster (``scheduler="local"``: a LocalCluster of ``workers`` processes)."""
    import dask as dask_module
    from distributed import Client, LocalCluster
    from distributed import as_completed as dask_completed

    cluster = None
    if scheduler == "local":
        # Dask's default worker environment sets MALLOC_TRIM_THRESHOLD_=65536, which makes the
        # allocation-heavy CasADi/IPOPT window solves several times slower (design notes: stored study runs);
        # keep its thread limits, drop the malloc setting.
        environ = dict(dask_module.config.get("distributed.nanny.pre-spawn-environ", {}))
        environ.pop("MALLOC_TRIM_THRESHOLD_", None)
        with dask_module.config.set({"distributed.nanny.pre-spawn-environ": environ}):
            cluster = LocalCluster(n_workers=workers or os.cpu_count(), threads_per_worker=1, processes=True)
    try:
        try:
            client = Client(cluster if cluster is not None else scheduler, timeout=SCHEDULER_TIMEOUT)
        except (OSError, TimeoutError, ValueError) as exc:
            raise OptionError(
                f"scheduler: no Dask scheduler answers at {scheduler!r} within {SCHEDULER_TIMEOUT:g} s ({exc})"
            ) from None
        with client:
            futures = client.map(run, tasks, pure=False)
            by_key = {future.key: task for future, task in zip(futures, tasks, strict=True)}
            try:
                for future in dask_completed(futures):
                    task = by_key[future.key]
                    try:
                        yield task, future.result(), ""
                    except Exception as exc:
                        if type(exc).__name__ == "KilledWorker":  # it killed a worker at every attempt
                            yield task, died_rows(task), ""
                        else:
                            yield task, None, f"{type(exc).__name__}: {exc}"
            finally:
                client.cancel(futures)
    finally:
        if cluster is not None:
            cluster.close()


def results(
    tasks: list[Task], run: Callable[[Task], Any], workers: int | None, scheduler: str | None
) -> Iterator[Outcome]:
    """The executor the options name: serial (one worker, no scheduler), processes, or Dask."""
    if scheduler is None and workers == 1:
        return serial(tasks, run)
    if scheduler is None:
        return processes(tasks, run, workers)
    return dask(tasks, run, workers, scheduler)
