"""The one place that chooses the task runner for fan-outs (the sweep's points).

``NNSF_TASK_RUNNER`` selects it:

- ``threads`` (default): :class:`prefect.task_runners.ThreadPoolTaskRunner`.
  The work is numpy/scipy, which releases the GIL, so threads use the cores
  without copying the feature matrix into other processes.
- ``processes``: :class:`prefect.task_runners.ProcessPoolTaskRunner`.
- ``dask``: ``prefect_dask.DaskTaskRunner`` (install ``prefect-dask``); set
  ``NNSF_DASK_ADDRESS`` to use an existing cluster, otherwise a local one
  is started.

``NNSF_WORKERS`` sets the number of workers (default: the number of cores).
"""
from __future__ import annotations

import os

from nnsf.errors import InputError

CHOICES = ("threads", "processes", "dask")


def workers() -> int:
    """How many sweep points run at once."""
    text = os.environ.get("NNSF_WORKERS", "")
    if text:
        if not text.isdigit() or int(text) < 1:
            raise InputError("environment", "NNSF_WORKERS", "an integer >= 1", text)
        return int(text)
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
               else (os.cpu_count() or 1))


def kind() -> str:
    """The configured runner name (validated)."""
    name = os.environ.get("NNSF_TASK_RUNNER", "threads")
    if name not in CHOICES:
        raise InputError("environment", "NNSF_TASK_RUNNER", "one of " + ", ".join(CHOICES), name)
    return name


def task_runner():
    """A fresh task runner as configured by the environment."""
    name, n = kind(), workers()
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
    address = os.environ.get("NNSF_DASK_ADDRESS")
    if address:
        return DaskTaskRunner(address=address)
    return DaskTaskRunner(cluster_kwargs={"n_workers": n, "threads_per_worker": 1})
