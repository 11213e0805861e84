"""A local pool of worker processes that survives the variants it runs.

Each worker is a spawned process (the Dr.Jit JIT does not survive ``fork``)
that runs its caller's warm-up once (the runner compiles the simulator's
kernels), then runs cases sent over a pipe and sends back one row per
variant as soon as it is scored (the caller's task function, e.g.
:func:`benchmarks.runner.case_rows`). The pool knows nothing of cases and
rows beyond those functions. Unlike a
:class:`concurrent.futures.ProcessPoolExecutor`, a worker that dies (out of
memory, a crash in native code) or stays silent beyond the time limit costs
only the variant it was running: that variant gets an error row, the
worker is replaced, and the case's remaining variants go back to the
queue. A memory limit (``RLIMIT_DATA``) per worker turns a runaway
allocation into a ``MemoryError`` that the variant reports, before the
kernel's out-of-memory killer picks a process on a shared machine.
"""

from __future__ import annotations

import collections
import multiprocessing
import multiprocessing.connection
import os
import resource
import signal
import threading
import time

from benchmarks.errors import BenchError

_READY = "ready"


def _exit_with_parent() -> None:
    """End this worker as soon as its parent process is gone (killed, even by SIGKILL)."""
    parent = multiprocessing.parent_process()
    if parent is None:
        return

    def watch():
        multiprocessing.connection.wait([parent.sentinel])
        os._exit(0)

    threading.Thread(target=watch, daemon=True).start()


def _worker(connection, memory_limit_bytes: int | None, run_task, warm_up) -> None:
    """Worker process: ``warm_up()``, then ``run_task(case, specs)`` for each task until told to stop (``None``).

    Ctrl-C reaches the whole process group: the worker ignores it and the
    parent stops the workers, so an interrupted run prints no worker
    traceback. A worker whose parent dies ends at once.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _exit_with_parent()
    if memory_limit_bytes:
        resource.setrlimit(resource.RLIMIT_DATA, (memory_limit_bytes, memory_limit_bytes))
    if warm_up is not None:
        warm_up()
    try:
        connection.send(_READY)
        while (task := connection.recv()) is not None:
            for row in run_task(*task):
                connection.send(row)
            connection.send(None)
    except (BrokenPipeError, EOFError, ConnectionResetError):
        os._exit(0)  # the parent went away: nothing to report to


class _Slot:
    """One worker process and the task it is running."""

    def __init__(self, context, memory_limit_bytes: int | None, run_task, warm_up):
        self.connection, child = context.Pipe()
        self.process = context.Process(target=_worker, args=(child, memory_limit_bytes, run_task, warm_up),
                                       daemon=True)
        self.process.start()
        child.close()
        self.ready = False
        self.task = None  # (case, specs not yet answered)
        self.since = time.monotonic()

    def assign(self, task) -> None:
        self.task = (task[0], list(task[1]))
        self.since = time.monotonic()
        self.connection.send(task)

    def collect(self) -> tuple[list[dict], bool]:
        """Rows received so far, and whether the worker is gone."""
        rows = []
        try:
            while self.connection.poll():
                message = self.connection.recv()
                self.since = time.monotonic()
                if message == _READY:
                    self.ready = True
                elif message is None:
                    self.task = None
                else:
                    rows.append(message)
                    self.task[1].pop(0)
        except (EOFError, OSError):
            return rows, True
        return rows, not self.process.is_alive()

    def stop(self) -> None:
        if self.process.is_alive():
            self.process.kill()
        self.process.join()
        self.connection.close()


def _death(exitcode: int | None) -> str:
    if exitcode is not None and exitcode < 0:
        name = signal.Signals(-exitcode).name
        return f"the worker process was killed by {name}" + (" (out of memory?)" if name == "SIGKILL" else "")
    return f"the worker process exited with status {exitcode}"


def run_local(todo: list[tuple[dict, list[dict]]], workers: int, run_task, failed_row, warm_up=None,
              memory_limit_gb: float | None = None, timeout_s: float | None = None):
    """Run ``(case, variant specs)`` tasks on local worker processes.

    Parameters
    ----------
    todo : list of (dict, list of dict)
        Cases (:meth:`~benchmarks.suite.Case.to_dict`) with the specs of the
        variants to run on each.
    workers : int
        Worker processes.
    run_task : callable
        ``run_task(case, specs)`` yields one result row per spec; a
        module-level function (workers are spawned and receive it by name).
    failed_row : callable
        ``failed_row(case, spec, reason)``: the row of a variant whose worker
        died or timed out.
    warm_up : callable, optional
        Run once by each worker before its first task.
    memory_limit_gb : float, optional
        Data-segment limit of each worker, GiB (``None`` or 0: none).
    timeout_s : float, optional
        Longest silence of a worker on a task (simulation plus one variant)
        before it is stopped and the variant recorded as timed out.

    Yields
    ------
    list of dict
        Result rows, as they arrive.

    Raises
    ------
    BenchError
        If a worker process cannot start.
    """
    context = multiprocessing.get_context("spawn")
    limit = int(memory_limit_gb * 2 ** 30) if memory_limit_gb else None
    queue = collections.deque(todo)
    slots = [_Slot(context, limit, run_task, warm_up) for _ in range(max(1, min(workers, len(todo))))]
    try:
        while queue or any(slot.task for slot in slots):
            for slot in slots:
                if slot.ready and slot.task is None and queue:
                    slot.assign(queue.popleft())
            multiprocessing.connection.wait([s.connection for s in slots] + [s.process.sentinel for s in slots],
                                            timeout=1.0)
            for index, slot in enumerate(slots):
                rows, gone = slot.collect()
                silent = timeout_s and slot.task and time.monotonic() - slot.since > timeout_s
                if gone and not slot.ready:
                    raise BenchError(f"a benchmark worker process could not start: {_death(slot.process.exitcode)}")
                if gone or silent:
                    slot.stop()
                    if slot.task:
                        case, pending = slot.task
                        reason = (f"no result within {timeout_s:g} s (stopped)" if silent
                                  else _death(slot.process.exitcode))
                        rows.append(failed_row(case, pending[0], reason))
                        if pending[1:]:
                            queue.appendleft((case, pending[1:]))
                    slots[index] = _Slot(context, limit, run_task, warm_up)
                if rows:
                    yield rows
    finally:
        for slot in slots:
            if slot.process.is_alive():
                try:
                    slot.connection.send(None)
                except OSError:
                    pass
            slot.process.join(timeout=5)
            slot.stop()
