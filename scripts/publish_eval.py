"""Publish a ``nnsf reshape-eval --out DIR`` run into ``reports/``: its tables as written, its contact sheets as JPEG by set.

    python scripts/publish_eval.py /tmp/eval reports

Copies ``reshape_eval.csv``, ``reshape_eval_frames.csv``, ``reshape_eval.json`` and ``reshape_fig8.png``,
and writes each ``reshape_eval/<drawing>_<motion>.png`` as ``reports/reshape_eval/<set>/<drawing>_<motion>.jpg``
(quality 85; ``<set>`` is ``tuning`` or ``heldout``, from the CSV), replacing the sheets of the last run.
JPEG because the sheets are for looking at and a full run's PNGs take about 60 MB.
"""
from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import cv2
import pandas as pd

TABLES = ("reshape_eval.csv", "reshape_eval_frames.csv", "reshape_eval.json", "reshape_fig8.png")
QUALITY = 85


def sheets_as_jpeg(src: Path, rows: pd.DataFrame, dst: Path, scale: float = 1.0) -> int:
    """Each contact sheet ``src/<drawing>_<motion>.png`` → ``dst/<set>/<drawing>_<motion>.jpg``, ``scale``
    times its size (``rows``: a ``reshape_eval.csv`` naming each item's set); returns how many."""
    sets = {f"{r.character}_{r.motion}": r.set for r in rows.itertuples()}
    if dst.exists():
        shutil.rmtree(dst)
    n = 0
    for png in sorted(src.glob("*.png")):
        folder = dst / sets[png.stem]
        folder.mkdir(parents=True, exist_ok=True)
        img = cv2.imread(str(png))
        if scale != 1.0:
            img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        cv2.imwrite(str(folder / f"{png.stem}.jpg"), img, [cv2.IMWRITE_JPEG_QUALITY, QUALITY])
        n += 1
    return n


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="the folder `nnsf reshape-eval --out` wrote")
    ap.add_argument("reports", type=Path)
    args = ap.parse_args(argv)
    for name in TABLES:
        shutil.copyfile(args.run / name, args.reports / name)
    n = sheets_as_jpeg(args.run / "reshape_eval", pd.read_csv(args.run / "reshape_eval.csv"),
                       args.reports / "reshape_eval")
    print(f"publish_eval: {len(TABLES)} tables and {n} sheets into {args.reports}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
