"""Question answered: does the reshaping hold up on motions it was never tuned on?

Every choice in ``nnsf/reshape`` was measured on the four motions of ``params.yaml``
``reshape_eval.motions``. This runs the same evaluation (:func:`nnsf.reshape.evaluation.run`: the same
drawings, every frame, the same measures) on six other clips from the data folder, none of which
was ever looked at while the method was built: a dab (AnimatedDrawings' fair1 ``dab``), a dance captured with Rokoko (``jesse_dance``), a Bandai-Namco
kick and dance, a boxing clip in 3ds Max's naming (``Boxing_Toes``) and a CMU clip in DAZ's naming
(``29_01``). The tuning drawings and the held-out ones are reported apart, as in reshape-eval.

    python -m experiments.heldout_motions --data /work/shared/data /work/extra-drawings /work/extra-drawings-tuning --out reports

Answer (``reports/reshape_heldout_motions.{csv,json}``, every frame of the first 240, the default
method): about as well as on the tuned motions. On the tuning drawings (27 × 6 = 162 clips, 38,880
frames) 9 frames have a detached piece (0.02 %: one each in gdquest_bear × dab,
noto_person_cartwheeling × Boxing_Toes and robot × dab, a 3 px tip of a claw, and 6 in
noto_person_juggling × Boxing_Toes and × 29_01, a 3-5 px fleck split off the sleeve's outer edge;
tuned motions 0 of 14,283), 41.8 % have cracks beyond the drawing's (34.7 %), 50.0 % a notch
(49.4 %) and 28.7 % spikes (29.2 %). On the held-out drawings (8 × 6 = 48 clips, 11,520 frames,
looked at only to check) 33 frames (0.29 %) have a detached piece, 20 of them gdquest_wolf ×
Boxing_Toes (tuned motions 7 of 4,232, 0.17 %); cracks 50.4 % (46.4 %), notches 48.7 % (48.7 %),
spikes 49.0 % (51.6 %).

Writes ``OUT/reshape_heldout_motions.csv`` (one row per drawing × motion × method, the columns of
``reshape_eval.csv``), ``OUT/reshape_heldout_motions.json`` (totals per set on these motions and, as
``tuned_*``, on the tuned ones from ``OUT/reshape_eval.csv`` when present; how it ran) and
``OUT/reshape_heldout_motions/<set>/<drawing>_<motion>.jpg`` (contact sheets at half size). A check,
not a measure of its own: it changes nothing that is measured.
"""
from __future__ import annotations

import argparse
import shlex
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

from nnsf import params as params_mod
from nnsf.io import write_csv, write_json
from nnsf.params import checked
from nnsf.reshape.evaluation import run
from scripts.publish_eval import sheets_as_jpeg

#: Clips inside the data folder that the method was never tuned on (the module docstring).
MOTIONS = ("animated-drawings/bvh/fair1/dab.bvh", "animated-drawings/bvh/rokoko/jesse_dance.bvh",
           "bandai-namco-1/data/dataset-1_kick_normal_001.bvh",
           "bandai-namco-1/data/dataset-1_dance-short_normal_001.bvh",
           "bvh-skeletons/3dsmax-style/Boxing_Toes.bvh", "bvh-skeletons/cmu-daz/29_01.bvh")
COUNTS = ("frames", "frames_with_detached", "frames_with_cracks", "frames_with_joint_cracks",
          "frames_notch_over_rest", "frames_spikes_over_rest")


def totals(df: pd.DataFrame) -> dict:
    """Per set, the default method's frame counts summed over its rows, and each as a share of frames."""
    out = {}
    for s, d in df[df["method"] == "ours"].groupby("set"):
        sums = {k: int(d[k].sum()) for k in COUNTS}
        out[s] = {**sums, "items": int(len(d)),
                  **{f"share_{k[len('frames_'):]}": round(sums[k] / max(sums["frames"], 1), 4) for k in COUNTS[1:]}}
    return out


def summary(df: pd.DataFrame, tuned: Path) -> dict:
    """:func:`totals` per set on these motions, each with the same totals on the tuned motions
    (``tuned``: a ``reshape_eval.csv``, if it exists) as ``tuned_<key>``."""
    sets, before = totals(df), totals(pd.read_csv(tuned)) if tuned.exists() else {}
    return {s: {**d, **{f"tuned_{k}": v for k, v in before.get(s, {}).items()}} for s, d in sets.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, nargs="+", help="data folders (drawings and motions)")
    ap.add_argument("--params", default="params.yaml", help="its reshape_eval section names the drawings")
    ap.add_argument("--out", type=Path, default=Path("reports"))
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args(argv)
    params = params_mod.load(a.params)

    def get(key, default):
        return checked(params, f"reshape_eval.{key}", default)

    t0 = time.perf_counter()
    from concurrent.futures import ProcessPoolExecutor

    def mapper(fn, xs):
        with ProcessPoolExecutor(a.workers) as ex:
            return list(ex.map(fn, xs))

    with tempfile.TemporaryDirectory() as tmp:
        run(a.data, Path(tmp), characters=tuple(get("characters", [])), heldout=tuple(get("heldout", [])),
            motions=MOTIONS, n_vertices=get("n_vertices", 800), max_frames=get("max_frames", 240),
            subkeys_per_limb=get("subkeys_per_limb", 4), mapper=mapper if a.workers > 1 else None)
        df = pd.read_csv(Path(tmp) / "reshape_eval.csv")
        sheets_as_jpeg(Path(tmp) / "reshape_eval", df, a.out / "reshape_heldout_motions", scale=0.5)
    write_csv(a.out / "reshape_heldout_motions.csv", df)
    write_json(a.out / "reshape_heldout_motions.json", {
        "motions": list(MOTIONS), "sets": summary(df, a.out / "reshape_eval.csv"),
        "seconds": round(time.perf_counter() - t0, 1),
        "command": "python -m experiments.heldout_motions " + shlex.join(argv if argv is not None else sys.argv[1:])})
    print(f"heldout_motions: {len(df) // 2} drawing x motion items into {a.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
