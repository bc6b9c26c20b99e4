"""The stages of the factor package: ``factorize``, ``styles`` and ``translate``.

* ``factorize``: NNSF (Eq. 5, the class term Eq. 7, multiplicative updates
  Eq. 8) on every frame, labelled by ``nnsf.label`` (docs/method.md §5-§6);
* ``styles``: the style translator (:class:`~nnsf.factor.translate.StyleTranslator`)
  fitted on every clip and saved (:mod:`nnsf.factor.style_model`);
  :func:`styles_by_hand` is ``nnsf styles`` on any folder;
* ``translate``: one clip's motion performed in another style (docs/method.md §8),
  written as tables, a stick-figure GIF and strip.
"""
from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from sklearn.metrics import precision_score
from threadpoolctl import threadpool_limits

from nnsf.datasets import contract
from nnsf.datasets.stage import data as data_stage
from nnsf.errors import InputError
from nnsf.factor.figures import basis_figure, objective_figure
from nnsf.factor.nnsf import NNSF
from nnsf.factor.style_model import (
    check_translator, dataset_fps, dataset_view, file_sha256, fit_model, translator_params, unify_table,
)
from nnsf.factor.translate import StyleTranslator, to_character_points
from nnsf.io import atomic_dir, read_json, write_json, write_npz
from nnsf.factor.style_names import check_aliases
from nnsf.params import Params, require, source_of
from nnsf.pipeline import (
    FEATURES_CSV, MODEL_PATH, REPORTS, STYLES_MODEL, TRANSLATION_DIR, StageResult, check_rank, label_column,
    nnsf_params, read_unifier,
)
from nnsf.publish import publish_stage
from nnsf.skeleton import Unifier

#: The camera views `nnsf styles` learns from a folder of motion capture.
MODEL_VIEWS: tuple[str, ...] = ("front", "side", "three-quarter")
from nnsf.stick import write_stick_gif, write_stick_strip


def translate(params: dict, features_csv=FEATURES_CSV, out_dir=TRANSLATION_DIR,
              content_clip=None, style=None) -> StageResult:
    """One clip's motion performed in another style (docs/method.md §8), to ``out_dir``.

    ``content_clip`` and ``style`` default to ``translation.content_clip`` and
    ``translation.style``; ``auto`` picks the first clip (sorted by name) and
    the last style, other than the clip's own, that has no clip of that
    content yet, else the last other style.  Writes ``translated_features.csv``
    (template units), ``translated_pixels.csv``, ``translation.gif``,
    ``translation_strip.png`` and ``translation.json``.
    """
    clip = str(content_clip if content_clip is not None else require(params, "translation.content_clip"))
    target = str(style if style is not None else require(params, "translation.style"))
    if clip == "auto" or target == "auto":
        table = contract.read_table(features_csv)
        clips = table.drop_duplicates("clip").set_index("clip").sort_index()
        if clip == "auto":
            clip = str(clips.index[0])
        if target == "auto" and clip in clips.index:
            own, content = clips.loc[clip, "character"], clips.loc[clip, "motion"]
            others = sorted(set(clips["character"]) - {own})
            if not others:
                raise InputError(features_csv, "character", "at least two styles to translate between")
            have = set(clips.loc[clips["motion"] == content, "character"])
            missing = [c for c in others if c not in have]
            target = str((missing or others)[-1])
    return translate_clip(params, features_csv=features_csv, unifier_json=Path(features_csv).parent / "unifier.json",
               content_clip=clip, style=target, out_dir=out_dir)


def styles(params: dict, features_csv=FEATURES_CSV, out=STYLES_MODEL, aliases=None) -> StageResult:
    """Fit the style translator (``translation.*``) on every clip and save it (``models/styles.npz``).

    The model file (:mod:`nnsf.factor.model_file`) holds the translator,
    the training characters' unifier (``unifier.json`` beside
    ``features_csv``), the view the dataset is seen in and the feature
    table's SHA-256; ``nnsf animate`` and :func:`nnsf.translate` apply it to
    new motion.
    """
    tp = translator_params(params)
    check_translator(params, tp)
    features_csv = Path(features_csv)
    table = contract.read_table(features_csv, non_negative=True)
    unifier = read_unifier(features_csv.parent)
    started = time.perf_counter()
    (view,) = fit_model([(dataset_view(params), table, unifier)], tp, out,
                        features_sha256=file_sha256(features_csv), source=str(features_csv),
                        fps=dataset_fps(params), aliases=aliases)
    seconds = time.perf_counter() - started
    tr = view.translator
    return StageResult(
        params={f"translation_{k}": v for k, v in tp.items()},
        metrics={"styles": len(tr.styles_), "contents": len(tr.contents_), "frames": len(table),
                 "fit_seconds": round(seconds, 3)},
        artifacts=[Path(out)])


def factorize(params: dict, features_csv=FEATURES_CSV, model=MODEL_PATH, reports=REPORTS) -> StageResult:
    """Fit NNSF on all frames, labelled by ``nnsf.label``.

    Writes the model (``U``, ``V``, ``W``, classes, per-row labels, objective
    history) as ``.npz``, ``reports/factorize.json`` and two figures: the
    objective per iteration and the basis rows drawn as poses.
    """
    rank = int(require(params, "nnsf.rank"))
    check_rank(params, rank, "nnsf.rank")
    kw = nnsf_params(params)
    max_iter = int(require(params, "nnsf.max_iter"))
    seed = int(require(params, "seed"))
    label = label_column(params)
    table = contract.read_features(features_csv)
    X = contract.features(table)
    y = table[label].to_numpy()

    started = time.perf_counter()
    est = NNSF(rank, max_iter=max_iter, random_state=seed, **kw)
    # One BLAS thread: the products are thin (34 columns), and OpenBLAS's
    # spinning worker threads made this fit 10-40x slower on a 2-core
    # machine with anything else running.
    with threadpool_limits(limits=1, user_api="blas"):
        V = est.fit_weights(X, y)
    seconds = time.perf_counter() - started
    U, W = est.components_, est.class_map_
    with threadpool_limits(limits=1, user_api="blas"):
        encoded = est.transform(X)  # the training frames encoded as new ones are
    train_pred = est.classes_[np.argmax(encoded @ W, axis=1)]
    metrics = {
        "n_iter": est.n_iter_,
        "objective": float(est.objective_[-1]),
        "relative_error": est.reconstruction_err_ / float(np.linalg.norm(X)),
        "train_precision": _macro_precision(y, train_pred),
        "v_sparsity": float(np.mean(V < 1e-6 * V.max())),
    }
    # The model and the reports are published as one set (nnsf.publish), under the
    # folder that holds both; the manifest is reports/factorize.manifest.json.
    model, reports = Path(model), Path(reports)
    root = Path(os.path.commonpath([model.parent.absolute(), reports.absolute()]))

    def write(out: Path) -> StageResult:
        write_npz(
            out / model.absolute().relative_to(root), U=U, V=V, V_encoded=encoded, W=W,
            classes=est.classes_.astype(str), objective=est.objective_,
            clip=table["clip"].to_numpy(str), character=table["character"].to_numpy(str),
            motion=table["motion"].to_numpy(str), label=np.array(label),
        )
        staged = out / reports.absolute().relative_to(root)
        figs = [
            objective_figure(est.objective_, staged / "figures" / "objective.png"),
            basis_figure(U, V, staged / "figures" / "basis.png"),
        ]
        # Files hold only what the inputs determine: wall time, and the iteration count
        # a tolerance decides (float noise of another CPU can move it), go to MLflow.
        write_json(staged / "factorize.json",
                   {"rank": rank, "label": label, **{k: v for k, v in metrics.items() if k != "n_iter"}})
        return StageResult(
            params={"rank": rank, "max_iter": max_iter, "seed": seed, "label": label, **kw},
            metrics={**metrics, "fit_seconds": round(seconds, 3)}, artifacts=figs,
        )

    result = publish_stage("factorize", reports, reports.absolute().relative_to(root) / "factorize.json",
                      write, root=root)
    result.artifacts = [reports / Path(a).relative_to(reports.absolute()) for a in result.artifacts]
    return result


def _macro_precision(y_true, y_pred) -> float:
    return float(precision_score(y_true, y_pred, average="macro", zero_division=0))




def styles_by_hand(params: dict, data=None, out=Path("models/styles.npz"), joint_map=None, aliases=None,
                   views=MODEL_VIEWS):
    """``nnsf styles``: fit and save a model from a features folder or a folder of BVH clips.

    ``data`` None reads ``data/features`` (the pipeline's configured
    dataset); a folder with ``features.csv`` and ``unifier.json`` is read as
    it is; any other folder is read as labelled BVH clips with the
    ``dataset.bvh`` settings (``joint_map``, a joint-map YAML, replaces
    ``dataset.bvh.joint_map``), projected in each of ``views`` (default:
    front, side and three-quarter) and unified with ``unify.margin``: one
    translator per view, all in one file, so ``nnsf animate`` finds the view
    its motion is seen in.  ``aliases`` (``{name: style}``) go into the model
    (:mod:`nnsf.factor.style_names`).  Returns the stage's
    :class:`~nnsf.pipeline.StageResult` and the BVH reader's report (skipped
    files, conflicts, duplicates, notes; one line each).
    """
    folder = Path("data/features") if data is None else Path(data)
    if not folder.is_dir():
        raise InputError(folder, "--data", "a folder of labelled .bvh clips or a features folder")
    if (folder / "features.csv").is_file():
        if aliases:
            table = contract.read_table(folder / "features.csv")
            check_aliases(aliases, table["character"], "--alias", "alias")
        return styles(params, features_csv=folder / "features.csv", out=out, aliases=aliases), []
    bad = [v for v in views if v not in MODEL_VIEWS]
    if bad or not views:
        raise InputError("--views", "views", "a non-empty list of " + ", ".join(MODEL_VIEWS), ",".join(views))
    tp = translator_params(params)
    check_translator(params, tp)
    fitted, frames, report = [], 0, []
    for view in views:
        bvh_params = Params(params)
        bvh_params.source = source_of(params)
        bvh = {**params.get("dataset", {}).get("bvh", {}), "view": view}
        if joint_map is not None:
            bvh["joint_map"] = str(joint_map)
        bvh_params["dataset"] = {**params.get("dataset", {}), "name": "bvh", "path": str(folder), "bvh": bvh}
        with tempfile.TemporaryDirectory(prefix="nnsf-styles-") as tmp:
            data_stage(bvh_params, out_dir=Path(tmp) / "raw")
            raw = contract.read_table(Path(tmp) / "raw" / "keypoints.csv")
            if not report:     # the folder reader reports the same files in every view
                report = list(read_json(Path(tmp) / "raw" / "characters.json").get("report", []))
        if aliases:
            check_aliases(aliases, raw["character"], "--alias", "alias")
        table, unifier = unify_table(raw, float(require(params, "unify.margin")), folder)
        fitted.append((view, table, unifier))
        frames = len(table)
    models = fit_model(fitted, tp, out, source=str(folder), fps=dataset_fps(bvh_params), aliases=aliases)
    tr = models[0].translator
    return StageResult(params={f"translation_{k}": v for k, v in tp.items()} | {"views": ",".join(views)},
                       metrics={"styles": len(tr.styles_), "contents": len(tr.contents_), "frames": frames,
                                "views": len(models)}, artifacts=[Path(out)]), report


def translate_clip(params: dict, features_csv=Path("data/features/features.csv"),
              unifier_json=Path("data/features/unifier.json"), content_clip: str = "", style: str = "",
              out_dir=Path("reports/translation")):
    """Stage/CLI: the motion of one clip performed in another style (docs/method.md §8).

    Fits a :class:`~nnsf.factor.translate.StyleTranslator` (``translation.*``)
    on every clip of ``features_csv`` and synthesises the content of
    ``content_clip`` in ``style``: with ``translation.synthesis: source``
    from that clip itself, X̂ = V_clip U_style (+ the clip's residual); with
    ``consensus`` from the content's shared weights, X̂ = V_content U_style
    (every clip of the content contributes).  X̂ goes back to pixels with the
    target character's inverse unification (``unifier_json``).

    Writes into ``out_dir``: ``translated_features.csv`` (the contract in
    template units), ``translated_pixels.csv`` (the contract in the target's
    pixels), ``translation.gif`` (source | translation | a real clip of the
    target style with that content, if any, in pixels), ``translation_strip.png``
    and ``translation.json``.  Rows are named ``{content_clip}-as-{style}``,
    ``character`` = ``style``, ``motion`` = the clip's content.

    Raises InputError naming ``content_clip`` or ``style`` when they are not
    in the table (with the choices), or bad ``translation.*`` parameters.
    """
    features_csv, unifier_json, out_dir = Path(features_csv), Path(unifier_json), Path(out_dir)
    tp = translator_params(params)
    synthesis = require(params, "translation.synthesis")
    check_translator(params, tp, synthesis)
    table = contract.read_table(features_csv, non_negative=True)
    clips = table["clip"].astype(str).to_numpy()
    chars = table["character"].astype(str).to_numpy()
    motions = table["motion"].astype(str).to_numpy()
    content_clip, style = str(content_clip), str(style)
    names = sorted(set(clips))
    if content_clip not in names:
        shown = ", ".join(names[:8]) + (", …" if len(names) > 8 else "")
        raise InputError(features_csv, "content_clip", f"a clip of the table ({shown})", content_clip)
    styles = sorted(set(chars))
    if style not in styles:
        raise InputError(features_csv, "style", f"a character (style) of the table: {styles}", style)
    unifier = Unifier.from_dict(read_json(unifier_json), unifier_json)
    if style not in unifier.scales:
        raise InputError(unifier_json, "characters", f"the target style {style!r}", sorted(unifier.scales))
    rows = clips == content_clip
    src_style, content = chars[rows][0], motions[rows][0]
    X = contract.features(table)
    tr = StyleTranslator(**tp).fit(X, motions, chars, clips)
    X_hat = tr.synthesize_cell(content, style, X[rows], src_style, synthesis=synthesis)
    P_hat = to_character_points(X_hat, style, unifier)
    name = f"{content_clip}-as-{style}"

    def frame(values):
        t = pd.DataFrame({"clip": name, "frame": np.arange(len(values)), "character": style,
                          "motion": content})
        return pd.concat([t, pd.DataFrame(values, columns=list(contract.COLUMNS[4:]))], axis=1)

    real = sorted(set(clips[(chars == style) & (motions == content)]) - {content_clip})
    seqs = [unifier.inverse_transform(X[rows], src_style), P_hat]
    titles = [f"source: {content_clip}", f"{content} as {style} (NNSF)"]
    if real:
        seqs.append(unifier.inverse_transform(X[clips == real[0]], style))
        titles.append(f"real: {real[0]}")
    fps = float(params.get("dataset", {}).get("bvh", {}).get("fps", 12)) \
        if params.get("dataset", {}).get("name") == "bvh" else 12.0
    with atomic_dir(out_dir) as tmp:
        contract.write_table(tmp / "translated_features.csv", frame(X_hat))
        contract.write_table(tmp / "translated_pixels.csv", frame(P_hat.reshape(len(P_hat), -1)))
        write_stick_gif(tmp / "translation.gif", seqs, titles=titles, fps=fps)
        write_stick_strip(tmp / "translation_strip.png", seqs, titles=titles, n_frames=8)
        write_json(tmp / "translation.json", {
            "content_clip": content_clip, "source_style": src_style, "content": content,
            "target_style": style, "frames": int(len(X_hat)), "synthesis": synthesis,
            "real_reference": real[0] if real else None,
            "files": ["translated_features.csv", "translated_pixels.csv", "translation.gif",
                      "translation_strip.png"]})
    return StageResult(
        params={"content_clip": content_clip, "style": style, "translation_synthesis": synthesis}
        | {f"translation_{k}": v for k, v in tp.items()},
        metrics={"frames": int(len(X_hat)), "feature_min": float(X_hat.min())},
        artifacts=[out_dir / "translation.gif", out_dir / "translation_strip.png",
                   out_dir / "translated_pixels.csv"])


