"""Rendering the frames of an animation on several processes.

:func:`render_frames` draws frame ``t`` of a deformed mesh with one
:class:`~nnsf.reshape.render.Renderer` call, as a serial loop would, and so gives the same bytes
whatever the number of workers.  With more than one worker, the frames are split into contiguous
chunks, each drawn by a process of a ``spawn`` pool straight into one shared-memory image array:

* spawn, not fork: the calling process may hold threads (OpenCV's pool,
  Prefect's and MLflow's workers) whose locks a forked child would inherit;
* the workers start without the caller's main script: a spawn child otherwise re-imports it, and
  a script that calls ``animate_files`` at top level (no ``if __name__ == "__main__"``) would run
  again in each worker.  The workers need only this module and the renderer's, imported by name;
* the renderer is pickled once per worker (its texture atlas, ~4 MB for a 700 px drawing) and
  the frames cross no pipe: the workers write them into one memory-mapped file (in ``/dev/shm``
  where there is one, so in memory), whose name is removed once they are done; the array
  returned maps it.  An interrupted render (Ctrl-C, SIGTERM under ``nnsf``) cancels the chunks
  not yet started and removes the file (an interrupt waits while the workers start, and the
  workers ignore Ctrl-C: no worker prints a traceback); the workers of a caller killed outright
  end with it; a file left by a process that was killed outright (its name holds the pid) is
  removed by the next pooled render (:func:`remove_stale`).

A spawn worker starts in a few tenths of a second (the interpreter, numpy and OpenCV: the renderer's
module imports no SciPy), so short clips are drawn in the calling process (:data:`MIN_FRAMES_PER_WORKER`).
"""
from __future__ import annotations

import os
import re
import signal
import sys
import tempfile
import threading
import types
from contextlib import contextmanager
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context, parent_process

import numpy as np

#: Frames each worker must have before a pool is worth its start-up (benchmarks/bench_animate.py:
#: a 512 px drawing on 2 cores renders 300 frames a little faster in two processes than in one).
MIN_FRAMES_PER_WORKER = 100

_RENDERER = None
#: The signals that stop a render: held while the workers start, ignored by the workers.
_STOPS = {signal.SIGINT, signal.SIGTERM}


def default_workers() -> int:
    """Worker processes for rendering: the CPUs this process may use, at most 8."""
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        n = os.cpu_count() or 1
    return max(1, min(8, n))


def _init(renderer) -> None:
    global _RENDERER
    _RENDERER = renderer
    # Ctrl-C reaches the whole process group: the caller cancels the chunks, and a worker
    # stopped by it would only print a traceback of its own.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOPS)  # held by the caller while it started us
    # A pool's worker waits for work on a queue whose write end it holds itself: if the caller is
    # killed outright, no end-of-file ever wakes it.  It watches the caller instead.
    threading.Thread(target=_exit_with_parent, name="nnsf-parent-watch", daemon=True).start()


def _exit_with_parent() -> None:
    parent = parent_process()
    if parent is not None:
        parent.join()  # returns when the caller's end of the start-up pipe closes: it has ended
        os._exit(1)


@contextmanager
def _stops_held():
    """SIGINT and SIGTERM wait, and then take effect, while the spawn workers start.

    The caller writes each worker its start-up data (the pickled renderer, megabytes) through a
    pipe.  An interrupt in the middle of that write leaves the worker a truncated pickle (its
    traceback on the terminal) or blocked on the rest of it, and the pool's shutdown waiting on that
    worker for ever.  So, in the main thread, the signals' handlers only note them until the workers
    are started; and the signals are blocked in this thread, a mask the workers inherit, so that a
    Ctrl-C sent to the whole process group meanwhile reaches no worker before :func:`_init` ignores
    it.
    """
    noted: list[int] = []
    main = threading.current_thread() is threading.main_thread()
    handlers = {s: signal.signal(s, lambda signum, frame: noted.append(signum)) for s in _STOPS} if main else {}
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, _STOPS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        for s, h in handlers.items():
            signal.signal(s, h)
        if noted:
            signal.raise_signal(noted[0])  # now handled as it would have been


def _draw(path: str, shape: tuple, start: int, frames: np.ndarray, orders: list, offset, background) -> None:
    """Draw ``frames`` ``(k, n, 2)`` into rows ``start:start + k`` of the mapped file."""
    out = np.memmap(path, np.uint8, mode="r+", shape=shape)
    for i, (v, order) in enumerate(zip(frames, orders)):
        out[start + i] = _RENDERER.render(v + offset, order, background=background)


@contextmanager
def _main_hidden():
    """While spawn workers start, ``__main__`` is an empty module: multiprocessing then gives
    them no main script to re-import (it reads ``__main__.__spec__`` / ``__file__`` at start)."""
    main = sys.modules.get("__main__")
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        if main is not None:
            sys.modules["__main__"] = main


def _memory_folder(nbytes: int) -> str | None:
    """``/dev/shm`` when it is writable with room for ``nbytes`` and a margin (containers often
    give it 64 MB, and a write beyond a full tmpfs kills the process); else None (the temp folder)."""
    try:
        st = os.statvfs("/dev/shm")
    except OSError:
        return None
    room = st.f_bavail * st.f_frsize
    return "/dev/shm" if os.access("/dev/shm", os.W_OK) and room > 2 * nbytes + (64 << 20) else None


_STALE = re.compile(r"nnsf-frames-(\d+)-.*\.u8")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process (EPERM): alive
        return True
    return True


def remove_stale(folder: str | None) -> list[str]:
    """Remove the frame files in ``folder`` (default: the temp folder) whose process is gone; returns their paths.

    A render killed outright (SIGKILL, a container stopped) leaves its file:
    in ``/dev/shm`` that is memory held until the next reboot.
    """
    folder = folder or tempfile.gettempdir()
    gone = []
    try:
        names = os.listdir(folder)
    except OSError:
        return gone
    for name in names:
        m = _STALE.fullmatch(name)
        if m and int(m.group(1)) != os.getpid() and not _alive(int(m.group(1))):
            try:
                os.unlink(os.path.join(folder, name))
                gone.append(os.path.join(folder, name))
            except OSError:  # removed meanwhile by another render, or not ours to remove
                pass
    return gone


def render_frames(renderer, frames: np.ndarray, orders, offset, background, size,
                  workers: int | None = None, progress=None, each=None, keep=True) -> np.ndarray | None:
    """RGB frames ``(T, H, W, 3)`` uint8 of a deformed mesh, ``frames`` ``(T, n, 2)`` px.

    ``orders``: per frame, the part order :meth:`~nnsf.reshape.render.Renderer.render` takes;
    ``offset`` ``(2,)`` is added to every vertex; ``size`` ``(H, W)``; ``background`` an RGB triple.
    ``workers``: processes (default :func:`default_workers`; 1 draws in this process, as does a clip
    shorter than :data:`MIN_FRAMES_PER_WORKER` frames per worker).  ``progress(done, total)`` is
    called after each chunk (each frame, when serial), ``each(image)`` with every frame in order
    once it is drawn (an encoder takes it while the rest are drawn).  ``keep=False``: None is
    returned, the frames go to ``each`` only, and a serial render holds no more than a frame.
    """
    T = len(frames)
    H, W = int(size[0]), int(size[1])
    workers = default_workers() if workers is None else max(1, int(workers))
    workers = min(workers, max(1, T // MIN_FRAMES_PER_WORKER))
    if workers == 1:
        images = np.empty((T, H, W, 3), np.uint8) if keep else None
        for t in range(T):
            image = renderer.render(frames[t] + offset, orders[t], background=background)
            if keep:
                images[t] = image
            if each is not None:
                each(image)
            if progress is not None:
                progress(t + 1, T)
        return images
    shape = (T, H, W, 3)
    folder = _memory_folder(int(np.prod(shape)))
    remove_stale(folder)
    fd, path = tempfile.mkstemp(prefix=f"nnsf-frames-{os.getpid()}-", suffix=".u8", dir=folder)
    os.close(fd)
    try:
        images = np.memmap(path, np.uint8, mode="w+", shape=shape)
        # Chunks of ~T / (4 · workers) frames: even load, progress now and then.  The workers take
        # them in order, so waiting for them in order hands ``each`` the frames with little delay.
        bounds = np.linspace(0, T, 4 * workers + 1).round().astype(int).tolist()
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=_init,
                                 initargs=(renderer,)) as pool:
            try:
                with _main_hidden(), _stops_held():  # the workers start at the first submits
                    jobs = [pool.submit(_draw, path, shape, a, np.asarray(frames[a:b]),
                                        list(orders[a:b]), offset, background)
                            for a, b in zip(bounds, bounds[1:])]
                for job, a, b in zip(jobs, bounds, bounds[1:]):
                    job.result()
                    if progress is not None:
                        progress(b, T)
                    for img in images[a:b] if each is not None else ():
                        each(img)
            except BaseException:
                # Interrupted or failed: the chunks not started are dropped (leaving the block
                # would otherwise wait for every one of them to be drawn).
                pool.shutdown(wait=True, cancel_futures=True)
                raise
    finally:
        os.unlink(path)  # the mapping stays valid; the file goes when the array does
    return images if keep else None
