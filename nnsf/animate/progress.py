"""Progress of a long job on the terminal: each phase that runs longer than a moment says so.

:class:`Phases` times the phases of a job (load, mesh, translate, deform,
render, encode).  A phase still running after :data:`HEARTBEAT` seconds gets a
line from a watcher thread, with how far it
got when the phase reports steps (``render: frame 40/120``) and the time so
far, so a user never watches a silent terminal for long; a phase that ran
that long also says when it ends.  Quick phases print nothing.
"""
from __future__ import annotations

import functools
import inspect
import sys
import threading
import time
from contextlib import contextmanager

__all__ = ["HEARTBEAT", "Phases", "phased"]

#: Seconds a phase may run silently; then a line every this many seconds.
HEARTBEAT = 2.0


class Phases:
    """Timed phases with a heartbeat on stderr.

    ``prefix`` starts every line (``"animate"``); ``enabled=False`` keeps the
    timing and prints nothing (the pipeline stage); ``every`` is the heartbeat
    in seconds (default :data:`HEARTBEAT`).  Wall and CPU seconds per phase end up in :attr:`seconds` and
    :attr:`cpu_seconds`.
    """

    def __init__(self, prefix: str, enabled: bool = True, every: float | None = None, stream=None):
        self.prefix, self.enabled = prefix, enabled
        self.every = float(HEARTBEAT if every is None else every)
        self.stream = sys.stderr if stream is None else stream
        self.seconds: dict[str, float] = {}
        self.cpu_seconds: dict[str, float] = {}
        self._step: tuple[int, int, str] | None = None
        self._lock = threading.Lock()

    def say(self, text: str) -> None:
        if self.enabled:
            print(f"{self.prefix}: {text}", file=self.stream, flush=True)

    def step(self, done: int, total: int, unit: str = "") -> None:
        """Record how far the running phase got (shown by the next heartbeat line)."""
        with self._lock:
            self._step = (int(done), int(total), unit)

    def start(self, name: str, what: str = "") -> None:
        """Begin phase ``name`` (ending the one running); ``what`` describes it in heartbeat lines."""
        self.stop()
        with self._lock:
            self._step = None
        self._current = (name, time.perf_counter(), time.process_time(), threading.Event())
        if self.enabled and self.every > 0:
            self._watcher = threading.Thread(target=self._beat, args=(name, what, self._current[1],
                                                                     self._current[3]), daemon=True)
            self._watcher.start()

    def stop(self) -> None:
        """End the running phase, if any, and add its time to :attr:`seconds`."""
        current, self._current = getattr(self, "_current", None), None
        if current is None:
            return
        name, t0, c0, stop = current
        stop.set()
        watcher, self._watcher = getattr(self, "_watcher", None), None
        if watcher is not None:
            watcher.join()
        wall = time.perf_counter() - t0
        self.seconds[name] = self.seconds.get(name, 0.0) + wall
        self.cpu_seconds[name] = self.cpu_seconds.get(name, 0.0) + time.process_time() - c0
        if wall >= self.every and self.enabled and self.every > 0:
            self.say(f"{name} done in {wall:.1f} s")

    @contextmanager
    def phase(self, name: str, what: str = ""):
        """The block as phase ``name`` (:meth:`start` ... :meth:`stop`)."""
        self.start(name, what)
        try:
            yield self
        finally:
            self.stop()

    def _beat(self, name: str, what: str, t0: float, stop: threading.Event) -> None:
        # Lines at 1, 2, 4 and then every 5 heartbeats: a minutes-long phase says where it
        # is a few times a minute, not every two seconds.
        wait = self.every
        while not stop.wait(wait):
            wait = min(2 * wait, 5 * self.every)
            with self._lock:
                step = self._step
            far = f" {step[0]}/{step[1]}{' ' + step[2] if step[2] else ''}," if step else ""
            self.say(f"{name}{': ' + what if what else ''} ...{far} {time.perf_counter() - t0:.0f} s")


def phased(prefix: str):
    """Decorate a job function that takes ``progress`` and ``phases`` arguments: it gets a
    :class:`Phases` (printing when ``progress`` is true), whose running phase is stopped however
    the job ends, so no heartbeat outlives it."""
    def decorate(fn):
        sig = inspect.signature(fn)

        @functools.wraps(fn)
        def run(*args, **kwargs):
            bound = sig.bind(*args, **kwargs)
            bound.apply_defaults()
            ph = Phases(prefix, enabled=bool(bound.arguments.get("progress", True)))
            bound.arguments["phases"] = ph
            try:
                return fn(*bound.args, **bound.kwargs)
            finally:
                ph.stop()
        return run
    return decorate
