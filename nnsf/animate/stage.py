"""The ``animate`` stage: the ``animate:`` block of params.yaml made into a video (:mod:`nnsf.animate.animation`)."""
from __future__ import annotations

from pathlib import Path

from nnsf.animate.animation import animate_files
from nnsf.datasets.views import check_view
from nnsf.io import atomic_dir, write_json
from nnsf.params import checked, require, source_of
from nnsf.pipeline import ANIMATE_DIR, STYLES_MODEL, StageResult


def animate(params: dict, model=STYLES_MODEL, out_dir=ANIMATE_DIR) -> StageResult:
    """The ``animate:`` block: a character performing a motion in a style (:mod:`nnsf.animate.animation`).

    Writes, atomically as one folder ``out_dir``: ``animation.mp4``,
    ``animation.gif``, ``animation_sheet.png`` (as ``animate.output`` lists)
    and ``animate.json`` (what was made, with the notes ``nnsf animate`` prints; no wall times,
    those go to MLflow).
    Character and motion paths must be relative and stay inside the project.
    """
    src = source_of(params)
    spec = {k: require(params, f"animate.{k}") for k in
            ("character", "motion", "style", "view", "fps", "n_vertices", "max_frames", "output")}
    spec["arms"] = checked(params, "animate.arms", None)     # absent: the character YAML's choice, else motion
    spec["head"] = checked(params, "animate.head", None)
    # Character and motion paths were checked by require() with nnsf.params.project_path, the
    # rule `nnsf check` applies: relative, inside the project once symbolic links are resolved.
    check_view(spec["view"], src, "animate.view")
    out_dir = Path(out_dir)
    with atomic_dir(out_dir) as tmp:
        outputs = {kind: tmp / name for kind, name in (("mp4", "animation.mp4"), ("gif", "animation.gif"),
                                                       ("sheet", "animation_sheet.png"))
                   if kind in spec["output"]}
        res = animate_files(spec["character"], spec["motion"], style=spec["style"], model=model,
                            view=spec["view"], fps=spec["fps"], n_vertices=int(spec["n_vertices"]),
                            max_frames=int(spec["max_frames"]), outputs=outputs, progress=False,
                            arms=spec["arms"], head=spec["head"])
        write_json(tmp / "animate.json", {
            "character": res.character, "motion": res.motion, "style": res.style, "view": res.view,
            "frames": res.frames, "fps": res.fps, "files": sorted(p.name for p in res.files.values()),
            "notes": list(res.notes)})
    return StageResult(
        params={f"animate.{k}": (",".join(v) if isinstance(v, list) else v) for k, v in spec.items()},
        metrics={"frames": res.frames, **{f"seconds_{k}": round(v, 3) for k, v in res.seconds.items()}},
        artifacts=[out_dir / p.name for p in res.files.values()] + [out_dir / "animate.json"])
