"""Figure: every AnimatedDrawings character performing three motions through ``nnsf animate``.

    .venv/bin/python scripts/animate_gallery.py --data ../shared/data --work /tmp/gallery \\
        --out reports/figures/animate_characters.png

For char1-char5 it runs the real command line three times: an AnimatedDrawings BVH
(``fair1/wave_hello``, front view) in a Bandai-Namco style, a Bandai-Namco walk (auto view: the
side) in another Bandai-Namco style, and a synthetic jump in the synthetic ``rex`` style of the
pipeline's ``models/styles.npz``.  char5, whose six arms are drawn spread, runs with
``--arms drawing`` (they swing about the drawn pose; with ``motion`` they hang behind the body).
char6, a pig drawn from the side, is read as a quadruped and sees both BVH motions from the side
(``--view side``).  Each MP4 is decoded back with OpenCV (so every run must give a
file that plays), and three of its frames go into one row of the figure.  The Bandai-Namco style
model is learned first with ``nnsf styles`` into the work folder.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

CHARACTERS = ("char1", "char2", "char3", "char4", "char5", "char6")
#: ``--arms`` per character (default ``motion``)
ARMS = {"char5": "drawing"}
#: ``--view`` per character for the BVH motions (default: the motion's own): a quadruped drawn from
#: the side walks in the plane a side view shows.
VIEWS = {"char6": "side"}


def motions(data: Path, work: Path):
    """(label, --motion, --style, --model, --view) of the three motions."""
    bandai = work / "bandai_styles.npz"
    return (("AD wave_hello as proud", data / "animated-drawings/bvh/fair1/wave_hello.bvh", "proud", bandai, "front"),
            ("Bandai walk as old", data / "bandai-namco-1/data/dataset-1_walk_normal_001.bvh", "old", bandai, "auto"),
            ("synthetic jump as rex", "synthetic:max/jump/48", "rex", Path("models/styles.npz"), None))


def frames_of(mp4: Path, picks=3) -> list[np.ndarray]:
    """``picks`` RGB frames spread over a decoded MP4; fails if the file does not play."""
    cap = cv2.VideoCapture(str(mp4))
    decoded = []
    ok, frame = cap.read()
    while ok:
        decoded.append(frame)
        ok, frame = cap.read()
    cap.release()
    if not decoded:
        raise SystemExit(f"{mp4}: OpenCV decoded no frame")
    idx = np.linspace(0, len(decoded) - 1, picks + 2)[1:-1].round().astype(int)
    return [cv2.cvtColor(decoded[i], cv2.COLOR_BGR2RGB) for i in idx], len(decoded)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", required=True, type=Path)
    ap.add_argument("--work", required=True, type=Path)
    ap.add_argument("--out", required=True, type=Path)
    a = ap.parse_args(argv)
    a.work.mkdir(parents=True, exist_ok=True)
    nnsf = [sys.executable, "-m", "nnsf.cli"]
    if not (a.work / "bandai_styles.npz").exists():
        subprocess.run(nnsf + ["styles", "--data", str(a.data / "bandai-namco-1"),
                               "--out", str(a.work / "bandai_styles.npz")], check=True)
    rows = []
    for char in CHARACTERS:
        for label, motion, style, model, view in motions(a.data, a.work):
            out = a.work / f"{char}_{label.split()[1]}.mp4"
            cmd = nnsf + ["animate", "--character", str(a.data / "animated-drawings/characters" / char),
                          "--motion", str(motion), "--style", style, "--model", str(model), "--out", str(out)]
            if view:
                cmd += ["--view", VIEWS.get(char, view)]
            if char in ARMS:
                cmd += ["--arms", ARMS[char]]
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
            picked, n = frames_of(out)
            print(f"{char} {label}: {n} frames decoded, {time.perf_counter() - t0:.1f} s", flush=True)
            note = f" (arms: {ARMS[char]})" if char in ARMS else (f" (view: {VIEWS[char]})" if view and char in VIEWS else "")
            rows.append((f"{char}: {label}" + note, picked))
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from nnsf.io import atomic_path
    fig, axes = plt.subplots(len(CHARACTERS), 9, figsize=(18, 2.3 * len(CHARACTERS)))
    for i, char in enumerate(CHARACTERS):
        for j in range(3):
            title, picked = rows[i * 3 + j]
            for k, img in enumerate(picked):
                ax = axes[i, j * 3 + k]
                ax.imshow(img)
                ax.set_axis_off()
                if k == 1:
                    ax.set_title(title, fontsize=8)
    fig.tight_layout()
    with atomic_path(a.out) as tmp:
        fig.savefig(tmp, dpi=80, format="png")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
