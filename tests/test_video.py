"""The MP4 and GIF writers: H.264 that plays in a browser, written whole or not at all.

The browser check runs Debian's ``chromium`` headless when it is installed (skipped otherwise),
with an OpenCV ``mp4v`` file as the control it must refuse.
"""
from __future__ import annotations

import ctypes
import itertools
import json
import os
import resource
import select
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import moving_box_frames as _frames
from nnsf.io import WriteError
from nnsf.reshape.video import read_gif, read_mp4, write_gif, write_mp4




def test_mp4_is_h264_yuv420p_at_even_size_and_decodes_back(tmp_path):
    import av

    imgs = _frames()
    path = write_mp4(tmp_path / "a.mp4", imgs, fps=12)
    with av.open(str(path)) as c:
        s = c.streams.video[0]
        assert s.codec_context.name == "h264" and s.codec_context.pix_fmt == "yuv420p"
        assert (s.codec_context.width, s.codec_context.height) == (88, 62)
        assert s.average_rate == 12 and float(s.duration * s.time_base) == pytest.approx(2.0, abs=0.09)
    back = read_mp4(path)
    assert back.shape == (24, 62, 88, 3)
    # lossy but close; the padding row and column are white
    assert np.abs(back[:, :61, :87].astype(int) - imgs).mean() < 3.0
    assert back[:, 61].min() > 235 and back[:, :, 87].min() > 235
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mp4"]          # no temporary left


def test_mp4_keeps_an_ntsc_rate_exact(tmp_path):
    import av

    path = write_mp4(tmp_path / "n.mp4", _frames(6), fps=30000 / 1001)
    with av.open(str(path)) as c:
        assert c.streams.video[0].average_rate.numerator == 30000


def _moving_disc(W, H=160, T=24):
    yy, xx = np.mgrid[:H, :W]
    return np.array([np.where(((xx - 9 * t % W) ** 2 + (yy - H // 2) ** 2 < 400)[..., None],
                              np.uint8([200, 40, 20]), np.uint8([250, 250, 250])) for t in range(T)])


def test_mp4_bytes_do_not_depend_on_the_cores_or_on_unwritten_memory(tmp_path):
    """Same frames, same bytes: on one core and on all (x264's thread count must not follow the
    cores), and when every fresh allocation holds a pattern (the encoder reads nothing it did not write)."""
    clip = _moving_disc(302)                           # 19 macroblocks wide: not a multiple of 8
    first = write_mp4(tmp_path / "a.mp4", clip, fps=12).read_bytes()
    cores = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else set()
    if len(cores) > 1:
        os.sched_setaffinity(0, {min(cores)})          # this thread, and the encoder threads it starts
        try:
            assert write_mp4(tmp_path / "b.mp4", clip, fps=12).read_bytes() == first
        finally:
            os.sched_setaffinity(0, cores)
    libc = ctypes.CDLL(None)
    if not hasattr(libc, "mallopt"):
        pytest.skip("no mallopt (not glibc): the unwritten-memory half needs M_PERTURB")
    libc.mallopt(-6, 1)                                # glibc's M_PERTURB: malloc fills what it returns with 0xfe
    try:
        assert write_mp4(tmp_path / "c.mp4", clip, fps=12).read_bytes() == first
    finally:
        libc.mallopt(-6, 0)


def test_gif_decodes_back_with_held_frames_counted(tmp_path):
    imgs = _frames(6)
    imgs[3] = imgs[2]                                   # a held frame: Pillow writes it once
    back = read_gif(write_gif(tmp_path / "a.gif", imgs, fps=10))
    assert len(back) == 5


class _FileSizeLimit:
    """``ulimit -f`` for this process while in the block: a write past ``kb`` fails with EFBIG
    as one on a full disk fails with ENOSPC (Python ignores SIGXFSZ), without a disk to fill."""

    def __init__(self, kb: int):
        self.kb = kb

    def __enter__(self):
        self.old = resource.getrlimit(resource.RLIMIT_FSIZE)
        resource.setrlimit(resource.RLIMIT_FSIZE, (self.kb * 1024, self.old[1]))

    def __exit__(self, *exc):
        resource.setrlimit(resource.RLIMIT_FSIZE, self.old)


def _limited(kb: int):
    def apply():
        resource.setrlimit(resource.RLIMIT_FSIZE, (kb * 1024, kb * 1024))
    return apply


@pytest.mark.parametrize("writer", [write_mp4, write_gif])
def test_a_full_disk_names_the_file_and_leaves_nothing(tmp_path, writer):
    out = tmp_path / "full" / ("a.mp4" if writer is write_mp4 else "a.gif")
    out.parent.mkdir()
    imgs = np.random.default_rng(0).integers(0, 255, (30, 120, 160, 3), dtype=np.uint8)
    with pytest.raises(WriteError) as err, _FileSizeLimit(16):
        writer(out, imgs, 12)
    assert str(err.value) == f"{out}: write: expected a file size the system allows (File too large [EFBIG])"
    assert list(out.parent.iterdir()) == []


@pytest.mark.slow
def test_animate_on_a_full_disk_exits_2_naming_the_mp4_and_leaves_nothing(tmp_path):
    nnsf = Path(sys.executable).with_name("nnsf")
    out = tmp_path / "full" / "a.mp4"
    out.parent.mkdir()
    r = subprocess.run([str(nnsf), "animate", "--character", "bruno", "--motion", "synthetic:bruno/walk/12",
                        "--out", str(out), "--vertices", "150", "--workers", "1"], capture_output=True,
                       text=True, preexec_fn=_limited(16), timeout=300, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    err = r.stderr.strip().splitlines()
    assert err[-1] == f"error: {out}: write: expected a file size the system allows (File too large [EFBIG])"
    assert "Traceback" not in r.stderr
    assert list(out.parent.iterdir()) == []


def test_a_write_error_inside_the_encoder_is_a_write_error(tmp_path, monkeypatch):
    import av

    def refuse(*a, **k):
        raise av.error.OSError(28, "No space left on device")   # what FFmpeg reports on ENOSPC
    monkeypatch.setattr(av.container.OutputContainer, "mux", refuse)
    with pytest.raises(WriteError, match=r"a\.mp4: write: expected free space on its disk"):
        write_mp4(tmp_path / "a.mp4", _frames(4), fps=12)
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- a browser plays it

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")

# The page settles a promise once the video has ended, failed or been refused; the test waits for it in
# real time over the DevTools pipe.  (A virtual-time budget does not wait for the media pipeline, so
# under load it reported a file that plays as unplayed.)
_PAGE = """<!doctype html><html><body>
<video id="v" src="{name}" muted playsinline></video>
<script>
const v = document.getElementById('v');
let played = false;
window.result = new Promise(settle => {{
  v.addEventListener('error', () => settle('error ' + (v.error ? v.error.code : '')));
  v.addEventListener('timeupdate', () => {{ played = played || v.currentTime > 0; }});
  v.addEventListener('ended', () => settle(`ok ${{v.videoWidth}} ${{v.videoHeight}} ${{v.duration}} ${{played}}`));
  v.addEventListener('loadedmetadata', () => v.play().catch(e => settle('play-error ' + e.name)));
}});
</script></body></html>
"""

_AWAIT = "new Promise(r => { const f = () => window.result ? window.result.then(r) : setTimeout(f, 50); f(); })"


def play_in_chromium(video: Path, timeout: float = 60.0) -> str:
    """What headless Chromium makes of ``video``: ``ok W H DURATION PLAYED``, ``error CODE`` or ``timeout``."""
    page = video.with_suffix(".html")
    page.write_text(_PAGE.format(name=video.name))
    profile = video.parent / f".chromium-{video.stem}"
    to_browser, from_browser = os.pipe(), os.pipe()

    def pipe_fds():                      # --remote-debugging-pipe reads fd 3 and writes fd 4
        os.dup2(to_browser[0], 3)
        os.dup2(from_browser[1], 4)

    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           f"--user-data-dir={profile}", "--allow-file-access-from-files",
           "--autoplay-policy=no-user-gesture-required", "--remote-debugging-pipe", page.as_uri()]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=pipe_fds,
                            pass_fds=(3, 4), env={**os.environ, "HOME": str(profile)})
    os.close(to_browser[0])
    os.close(from_browser[1])
    deadline, buffer, calls = time.monotonic() + timeout, b"", itertools.count(1)

    def call(method, session=None, **params):
        ident = next(calls)
        message = {"id": ident, "method": method, "params": params} | ({"sessionId": session} if session else {})
        os.write(to_browser[1], json.dumps(message).encode() + b"\0")
        nonlocal buffer
        while True:
            while b"\0" in buffer:
                raw, buffer = buffer.split(b"\0", 1)
                reply = json.loads(raw)
                if reply.get("id") == ident:
                    return reply.get("result", reply)
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([from_browser[0]], [], [], left)[0]:
                raise TimeoutError
            chunk = os.read(from_browser[0], 1 << 16)
            if not chunk:
                raise TimeoutError
            buffer += chunk

    try:
        targets = call("Target.getTargets")["targetInfos"]
        target = next(t["targetId"] for t in targets if t["type"] == "page")
        session = call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        while True:                      # an evaluation that the page's own load interrupts is asked again
            reply = call("Runtime.evaluate", session, expression=_AWAIT, awaitPromise=True,
                         returnByValue=True)
            if "result" in reply:
                return reply["result"].get("value", str(reply))
    except (TimeoutError, StopIteration, KeyError) as err:
        return f"timeout {type(err).__name__}"
    finally:
        proc.kill()
        proc.wait()
        os.close(to_browser[1])
        os.close(from_browser[0])


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (apt-get install -y chromium)")
def test_headless_chromium_plays_the_mp4_at_its_size_and_duration(tmp_path):
    import cv2

    path = write_mp4(tmp_path / "a.mp4", _frames(), fps=12)
    width, height, duration, played = play_in_chromium(path).split()[1:]
    assert (int(width), int(height)) == (88, 62)
    assert float(duration) == pytest.approx(2.0, abs=0.09) and played == "true"
    # The control: MPEG-4 Part 2 from OpenCV's writer, which this browser refuses.
    bad = tmp_path / "b.mp4"
    vw = cv2.VideoWriter(str(bad), cv2.VideoWriter_fourcc(*"mp4v"), 12.0, (88, 62))
    for img in _frames():
        vw.write(cv2.resize(img, (88, 62)))
    vw.release()
    assert play_in_chromium(bad).startswith("error"), "the browser check cannot tell a bad file"
