"""Held-out translation rows for the GP baselines, by the protocol of ``evaluate_cell``.

Until ``mgpm`` and ``cbgpm`` are methods of ``nnsf.evaluate.translation`` this script replays
that protocol for them: for each of ``max_cells`` held-out cells (spread over the grid as the
``heldout`` stage picks them) it refits the unifier, the clip classifiers, the bilinear model
(rank 1, with the source residual) and both GP models (``gp_rank``, 3 phase bins, 50 L-BFGS
iterations) without the cell, translates every remaining clip of the content into the hidden
style and prints the DTW error and the style/content accuracies.  ``evaluate_cell`` itself is
run for bilinear + identity on the same cells and its bilinear error is printed beside the
replayed one: equal numbers show that the protocol is the stage's.

    .venv/bin/python benchmarks/heldout_gp.py data/features/features.csv heldout_gp.csv [12] [8]
"""
import sys, time
import numpy as np, pandas as pd
from threadpoolctl import threadpool_limits
from nnsf.datasets import contract
from nnsf.datasets.contract import features
from nnsf.evaluate import translation as tr
from nnsf.evaluate.gp_translation import fit_gp_translator, gp_translate
from nnsf.factor.baselines import BilinearModel
from nnsf.skeleton import Unifier, to_points

table = contract.read_table(sys.argv[1])
out_csv = sys.argv[2]
max_cells = int(sys.argv[3]) if len(sys.argv) > 3 else 12
gp_rank = int(sys.argv[4]) if len(sys.argv) > 4 else 8
cells = tr._pick(tr.grid_cells(table), max_cells)
rows = []
with threadpool_limits(1):
  for style, content in cells:
    t0 = time.perf_counter()
    ref = tr.evaluate_cell(table, style, content, methods=("bilinear", "identity"), bilinear_rank=1, margin=0.5)
    hidden = tr._check_cell(table, style, content)
    train = table.loc[~hidden].reset_index(drop=True); test = table.loc[hidden].reset_index(drop=True)
    P = to_points(features(train)); ch = train["character"].astype(str).to_numpy(); mo = train["motion"].astype(str).to_numpy()
    unifier = Unifier(margin=0.5).fit(P, ch)
    X = unifier.transform(P, ch)
    names, rws = tr._clip_index(train)
    cs = np.array([ch[r[0]] for r in rws]); cc = np.array([mo[r[0]] for r in rws])
    h_names, h_rows = tr._clip_index(test)
    Pt = to_points(features(test))
    hidden_X = [tr._unify(unifier, Pt[r], style) for r in h_rows]
    grid_contents = {c for s, c in tr.grid_cells(train)} | {content}
    keep = np.isin(cc, sorted(grid_contents))
    F = np.stack([tr.clip_features(X[r]) for r in rws])
    clf = tr.ClipClassifiers().fit(F[keep], cs[keep], cc[keep])
    src = np.flatnonzero(cc == content)
    clip = train["clip"].astype(str).to_numpy()
    models = {m: fit_gp_translator(m, X, mo, ch, clip, rank=gp_rank, phase_bins=3, max_iter=50) for m in ("mgpm", "cbgpm")}
    others = ch != style
    bil = BilinearModel(n_components=1).fit(X[others], mo[others], ch[others])
    own = ~others & np.isin(mo, bil.classes_); bil.adapt_style(X[own], mo[own], style)
    sums = {m: dict(dtw=0.0, n=0, style=0, content=0, k=0) for m in ("bilinear", "identity", "mgpm", "cbgpm")}
    for q in src:
        Xs = X[rws[q]]; s_src = cs[q]
        B = bil.transform(Xs, np.full(len(Xs), s_src))
        hats = {"bilinear": bil.inverse_transform(B, np.full(len(Xs), style)) + Xs - bil.inverse_transform(B, np.full(len(Xs), s_src)),
                "identity": Xs}
        for m, model in models.items():
            hats[m] = gp_translate(model, Xs, s_src, style, content)
        for Xh in hidden_X:
            for m, (err, _) in tr._compare(hats, Xh).items():
                sums[m]["dtw"] += err; sums[m]["n"] += 1
        for m, Xh in hats.items():
            f = tr.clip_features(Xh)
            sums[m]["style"] += int(clf.predict_style(f, content)[0] == style)
            sums[m]["content"] += int(clf.predict_content(f, style)[0] == content)
            sums[m]["k"] += 1
    for m, s in sums.items():
        rows.append({"style": style, "content": content, "method": m, "dtw_error": s["dtw"] / s["n"],
                     "style_acc": s["style"] / s["k"], "content_acc": s["content"] / s["k"]})
    chk = ref.set_index("method")
    mine = {r["method"]: r for r in rows[-4:]}
    print(style, content, f"{time.perf_counter()-t0:.1f}s", "check bilinear", round(chk.loc["bilinear", "dtw_error"], 5), round(mine["bilinear"]["dtw_error"], 5),
          "| dtw", {m: round(mine[m]["dtw_error"], 4) for m in mine}, flush=True)
res = pd.DataFrame(rows)
res.to_csv(out_csv, index=False)
print(res.groupby("method", sort=False)[["dtw_error", "style_acc", "content_acc"]].mean().round(4).to_string())
