"""The one place that chooses the task runner and fans work out on it.

Every fan-out of the pipeline (sweep points, CV folds, per-clip tracking,
per-cell evaluation) goes through two functions:

- :func:`configured` gives a flow the task runner chosen by the environment;
- :func:`prefect_mapper` makes the ``mapper(fn, items) -> list`` that the
  ``nnsf`` stage functions accept: one Prefect task run per item, on the
  running flow's task runner, results in the items' order.

Each fan-out gets the runner that suits its items (:data:`DEFAULTS`, the rule
below); ``NNSF_TASK_RUNNER`` set to one of these names overrides it for all:

- ``threads``: :class:`prefect.task_runners.ThreadPoolTaskRunner`.  Threads
  start at once and copy nothing.  numpy releases the GIL inside its
  products, but the default dataset's fits are small (about 9,000 x 34) and
  hold it between them, so two threads gain little over one there
  (``benchmarks/bench_sweep.py``).
- ``processes``: :class:`prefect.task_runners.ProcessPoolTaskRunner`.  Each
  worker process pays its start-up (imports, about 3-6 s) once and each item
  is pickled to it, but the workers share no GIL.
- ``dask``: ``prefect_dask.DaskTaskRunner``.  ``NNSF_DASK_ADDRESS``
  (``tcp://host:8786``) submits to an existing Dask scheduler; without it a
  local cluster of ``NNSF_WORKERS`` single-threaded worker processes lives
  for the flow run.

The rule (measured with ``benchmarks/bench_fanout.py``): **processes for few, large items**,
items that each compute for seconds in Python and numpy between BLAS calls
(a held-out cell refits eleven methods on the remaining clips: 4-30 s), where
a worker's start-up and a copy of its input are small beside the item and a
shared GIL is what limits threads; **threads for many small items** (CV fits
and sweep points of 0.03-1 s, clips to render or track), where a process
pool's start-up would cost more than it saves.  Dask is never the default:
on one machine it ships each held-out cell's input through its scheduler and
was the slowest; use it for more machines.

``NNSF_WORKERS`` sets the number of local workers (default: the number of
cores).  No pool or scheduler of our own: retries, task states and the UI's
view of every item are Prefect's, placement is the runner's.
"""
from __future__ import annotations

import os
from typing import Any, Callable, Iterable

from nnsf.errors import InputError, exception_line

from flows import project

CHOICES = ("threads", "processes", "dask")
#: Default number of retries of one item: a worker lost with its machine, a
#: database that was busy.  Bad input is never retried.
RETRIES = 2
RETRY_DELAY_S = 1.0


def workers() -> int:
    """How many items run at once on a local runner."""
    text = os.environ.get("NNSF_WORKERS", "")
    if text:
        if not text.isdigit() or int(text) < 1:
            raise InputError("environment", "NNSF_WORKERS", "an integer >= 1", text)
        return int(text)
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
               else (os.cpu_count() or 1))


#: The runner of each fan-out (by stage) when ``NNSF_TASK_RUNNER`` is not set; the rule is in
#: the module docstring.  Every other fan-out (evaluate's CV fits, the sweep's points, frames,
#: roto and roto_eval's clips) runs on :data:`DEFAULT`.
DEFAULTS = {"heldout": "processes"}
DEFAULT = "threads"


def kind(fan_out: str | None = None) -> str:
    """The runner name for ``fan_out`` (a stage name): ``NNSF_TASK_RUNNER`` if set (validated),
    else the fan-out's default (:data:`DEFAULTS`)."""
    name = os.environ.get("NNSF_TASK_RUNNER") or DEFAULTS.get(fan_out, DEFAULT)
    if name not in CHOICES:
        raise InputError("environment", "NNSF_TASK_RUNNER", "one of " + ", ".join(CHOICES), name)
    return name


def dask_address() -> str | None:
    """``NNSF_DASK_ADDRESS`` if set (only meaningful with ``NNSF_TASK_RUNNER=dask``)."""
    return os.environ.get("NNSF_DASK_ADDRESS") or None


def task_runner(fan_out: str | None = None):
    """A fresh task runner for ``fan_out`` (a stage name), as the rule and the environment say."""
    name, n = kind(fan_out), workers()
    if name == "threads":
        from prefect.task_runners import ThreadPoolTaskRunner

        return ThreadPoolTaskRunner(max_workers=n)
    if name == "processes":
        from prefect.task_runners import ProcessPoolTaskRunner

        return ProcessPoolTaskRunner(max_workers=n)
    try:
        from prefect_dask import DaskTaskRunner
    except ImportError:
        raise InputError("environment", "NNSF_TASK_RUNNER",
                         "'dask' only with the prefect-dask package installed") from None
    address = dask_address()
    if address:
        return DaskTaskRunner(address=address)
    # One thread per worker process: the items are BLAS-bound and a second
    # thread per worker would oversubscribe the cores.
    return DaskTaskRunner(cluster_kwargs={"n_workers": n, "threads_per_worker": 1,
                                          "processes": True, "dashboard_address": None})


def configured(flow_obj, fan_out: str | None = None):
    """``flow_obj`` with the task runner of ``fan_out`` (a copy; the original is unchanged).

    Call it when the flow is about to run (not at import), so the environment
    of that run decides: ``configured(stage_flows.heldout, "heldout")(params)``.
    """
    return flow_obj.with_options(task_runner=task_runner(fan_out))


class FanOutError(RuntimeError):
    """Some items of a fan-out failed (after their retries); the others finished.

    Attributes
    ----------
    failed : dict[str, BaseException]
        The final error of every failed item, by item name.
    results : list
        One entry per item in order: the result, or ``None`` where it failed.
    """

    def __init__(self, task_name: str, failed: dict[str, BaseException], results: list):
        self.task_name, self.failed, self.results = task_name, failed, results
        shown = "; ".join(f"{name}: {exception_line(err, with_type=False)}" for name, err in failed.items())
        super().__init__(f"{task_name}: {len(failed)} of {len(results)} items failed: {shown}")


class FanOutInputError(FanOutError, InputError):
    """Every failed item failed on bad input: reported like any :class:`InputError`."""

    def __init__(self, task_name: str, failed: dict[str, BaseException], results: list):
        FanOutError.__init__(self, task_name, failed, results)
        first = next(iter(failed.values()))
        self.source = getattr(first, "source", task_name)
        self.field = ", ".join(failed)
        self.expected = str(first)
        self.got = None


def retry_unless_bad_input(task, task_run, state) -> bool:
    """Prefect's retry condition: retry anything but an :class:`InputError`."""
    try:
        state.result()
    except InputError:
        return False
    except BaseException:
        return True
    return True


def _escape(label: str) -> str:
    # Prefect formats task-run names with the call's parameters (str.format).
    return label.replace("{", "{{").replace("}", "}}")


def prefect_mapper(task_name: str, retries: int = RETRIES,
                   retry_delay_seconds: float = RETRY_DELAY_S,
                   name: Callable[[Any], str] | None = None,
                   on_result: Callable[[Any, Any], None] | None = None):
    """A ``mapper(fn, items) -> list`` that runs one Prefect task per item.

    Use it inside a running flow (give the flow a runner with
    :func:`configured`).  ``fn`` must be a module-level function of one
    picklable argument (the process and Dask runners send it by reference);
    every item is submitted at once and the runner decides how many run
    together.

    Parameters
    ----------
    task_name : str
        Name of the task in Prefect's UI, e.g. ``"sweep-point"``, ``"cv-fold"``.
    retries, retry_delay_seconds
        Prefect retries per item for unexpected errors; an
        :class:`~nnsf.errors.InputError` is final at once.
    name : callable, optional
        ``name(item) -> str`` for error reports; default ``"[<index>]"``.  Task
        runs are named ``"<task_name> <name>"``.
    on_result : callable, optional
        ``on_result(item, result)``, called on the flow's thread as each item
        finishes (in completion order), e.g. to log it before the others end.

    Returns the results in the items' order.  If items failed, every other
    item still runs to the end, then :class:`FanOutInputError` (all failures
    are bad input) or :class:`FanOutError` is raised, naming the failed items
    and carrying the finished results.
    """
    def mapper(fn: Callable[[Any], Any], items: Iterable[Any]) -> list:
        from prefect import task
        from prefect.cache_policies import NO_CACHE
        from prefect.futures import as_completed
        from threadpoolctl import threadpool_limits

        items = list(items)
        labels = [name(item) if name else f"[{i}]" for i, item in enumerate(items)]
        recording = bool(os.environ.get("NNSF_RECORD_IMPORTS"))
        base = task(_recorded if recording else fn, name=task_name, retries=retries,
                    retry_delay_seconds=retry_delay_seconds,
                    retry_condition_fn=retry_unless_bad_input, cache_policy=NO_CACHE,
                    persist_result=False)
        # Items on the thread runner share this process's BLAS pool: one BLAS thread for the
        # whole fan-out, set once here, so that a sum does not depend on what else runs.  (A
        # limit set and restored per item, as a fit does, let an item still running go on with
        # two threads when another one ended, and round differently: a CV fit's iteration count
        # changed between two cold runs.)  Worker processes set their own.
        with threadpool_limits(1, user_api="blas"):
            futures = [base.with_options(task_run_name=_escape(f"{task_name} {label}"))
                       .submit((fn, item) if recording else item)
                       for label, item in zip(labels, items)]
            position = {f.task_run_id: i for i, f in enumerate(futures)}
            results: list = [None] * len(items)
            failed: dict[int, BaseException] = {}
            for future in as_completed(futures):
                i = position[future.task_run_id]
                try:
                    results[i] = future.result()
                    if recording:
                        results[i], files = results[i]
                        WORKER_FILES.update(files)
                except BaseException as err:  # noqa: BLE001  (reported by name below)
                    if isinstance(err, (KeyboardInterrupt, SystemExit)):
                        raise
                    failed[i] = err
                    continue
                if on_result is not None:
                    on_result(items[i], results[i])
        if failed:
            by_name = {labels[i]: failed[i] for i in sorted(failed)}
            cls = (FanOutInputError if all(isinstance(e, InputError) for e in by_name.values())
                   else FanOutError)
            raise cls(task_name, by_name, results)
        return results

    return mapper


#: The project's module files that fan-out items loaded in worker processes (process pool,
#: Dask), collected only under ``NNSF_RECORD_IMPORTS``: what the stage ran beyond the modules
#: of its own process (flows.__main__ writes both; the pipeline test compares them with deps).
WORKER_FILES: set[str] = set()


def _recorded(call):
    """``fn(item)`` and the project files loaded in the process that ran it (a worker's, too)."""
    fn, item = call
    return fn(item), project.loaded_files()


def local_mapper(fn: Callable[[Any], Any], items: Iterable[Any]) -> list:
    """The mapper without Prefect: ``list(map(fn, items))`` (the stages' default)."""
    return [fn(item) for item in items]
