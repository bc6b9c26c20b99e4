"""The ``nnsf`` command: each pipeline stage as a plain command, without orchestration.

    nnsf frames|roto|roto_eval|data|features|factorize|evaluate|isomap|heldout|results [--params FILE]
    nnsf roto [--export-cvat DIR] [--corrections FILE.xml [--clip CLIP]]
                                        tracks out to CVAT; corrected frames back in as keyframes
    nnsf sweep [--params FILE]          every sweep point in turn, a CSV on stdout
    nnsf check [--params FILE]          validate params.yaml and exit
    nnsf translate --clip CLIP --style STYLE [--out DIR]
                                        one clip's motion performed in another style
    nnsf reshape [--motion CSV] [--clip CLIP] [--character NAME|FILE|FOLDER] [--joints FILE] [--out DIR]
                                        a drawn character performing a motion clip
    nnsf styles [--data FOLDER] [--out FILE] [--joint-map FILE.yaml] [--alias NAME=STYLE ...]
                [--neutral STYLE] [--views front,side,three-quarter]
                                        fit the style model and save it (default models/styles.npz);
                                        motion capture is learned in every view; works in any
                                        folder (package defaults without a params.yaml)
    nnsf animate --character C --motion M [--style NAME|none] [--model FILE]
                 [--view front|side|three-quarter|auto] [--arms motion|drawing] [--head motion|torso]
                 [--out FILE.mp4|FILE.gif|DIR] [--fps N] [--workers N] [--joint-map FILE.yaml]
                 [--keypoints FILE.csv]
                                        your character performing your motion in a learned style
    nnsf bvh-info FILE.bvh [--joint-map FILE.yaml]
                                        a BVH file's hierarchy, frames, skeleton family, key points
                                        and the view it moves most in
    nnsf reshape-eval --data DIR [--out DIR] [--workers N]
                                        the reshaping evaluation: the drawings and motions of
                                        params.yaml reshape_eval, found under each DIR
    nnsf roto-real --data DIR --annotations DIR [--format frames|lpc] [--name STEM] [--out DIR]
                                        the trackers on annotated real frames (folders of RGBA
                                        frames, or LPC sprite sheets) vs their silhouettes

The same stages run as Prefect flows with MLflow logging through
``python -m flows <stage>`` (what ``dvc repro`` calls).  Exit codes: 0 done,
2 bad input (one ``error: …`` line on stderr naming the file and field),
1 anything else (one line; ``NNSF_DEBUG=1`` shows the traceback).
"""
from __future__ import annotations

import argparse
import errno
import os
import signal
import sys
import threading
from pathlib import Path

from nnsf.errors import InputError, OneLineParser, exception_line, one_line, terminate_as_interrupt
from nnsf.io import check_replaceable, read_json
from nnsf.params import STAGE_NAMES
from nnsf.schema import List, Optional, Record, Str

#: The part of reshape's metrics.json the command reads back: its notes, each printed on one line.
RESHAPE_NOTES = Record({"notes": Optional(List(Str(max_len=10_000), max_len=1000))}, extra=True)

#: OS errors that mean "this output cannot be written here": reported like bad input (exit 2).
UNWRITABLE = {errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOTDIR, errno.EISDIR, errno.ENOSPC,
              errno.EDQUOT}

#: The stages run as plain ``nnsf <stage>`` on params.yaml (the others have commands of their own).
STAGES = tuple(s for s in STAGE_NAMES if s not in ("sweep", "translate", "reshape", "styles", "animate"))


def _parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="nnsf", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog=__doc__.split("\n\n", 1)[1])
    sub = parser.add_subparsers(dest="command", required=True, metavar="command")
    params_help = "parameters file (default: params.yaml in the current folder)"
    for name in STAGES + ("sweep", "check"):
        p = sub.add_parser(name, help=f"the {name} stage" if name in STAGES else None)
        p.add_argument("--params", default="params.yaml", help=params_help)
        if name == "roto":
            p.add_argument("--corrections", type=Path, default=None, metavar="FILE.xml",
                           help="a CVAT for video 1.1 file of corrected tracks: its corrected frames "
                                "become keyframes and only the intervals they touch are re-tracked")
            p.add_argument("--clip", default=None, help="the clip of --corrections (default: its task name)")
            p.add_argument("--export-cvat", type=Path, default=None, metavar="DIR",
                           help="also write DIR/<clip>.xml (CVAT for video 1.1) of every clip's tracks")

    p = sub.add_parser("translate", help="one clip's motion performed in another style")
    p.add_argument("--params", default="params.yaml", help=params_help)
    p.add_argument("--features", type=Path, default=Path("data/features/features.csv"),
                   help="unified feature table (its unifier.json beside it)")
    p.add_argument("--clip", default=None, help="the content clip (default: translation.content_clip)")
    p.add_argument("--style", default=None, help="the target style (default: translation.style)")
    p.add_argument("--out", type=Path, default=Path("reports/translation"))

    p = sub.add_parser("reshape", help="a drawn character performing a motion clip")
    p.add_argument("--params", default="params.yaml", help=params_help)
    p.add_argument("--motion", type=Path, default=Path("reports/translation/translated_features.csv"),
                   help="a feature-matrix CSV (any 17-point clip: synthetic, BVH, tracked, translated)")
    p.add_argument("--clip", default=None, help="its clip (default: reshape.clip, else the first)")
    p.add_argument("--character", default=None,
                   help="a built-in character name, or an AnimatedDrawings folder (extra arms and "
                        "quadrupeds too), joints YAML beside its PNG or character JSON (default: reshape.character)")
    p.add_argument("--joints", type=Path, default=None,
                   help="joints YAML (or nnsf.keypoints JSON) for a PNG --character")
    p.add_argument("--out", type=Path, default=Path("reports/reshape"))

    p = sub.add_parser("styles", help="fit the style model and save it")
    p.add_argument("--params", default=None,
                   help="parameters file (its dataset.bvh, unify, translation and seed settings); default: "
                        "params.yaml in the current folder, else the package defaults (a note says so)")
    p.add_argument("--data", type=Path, default=None,
                   help="a folder of labelled .bvh clips, or a features folder (features.csv, unifier.json); "
                        "default: data/features (the pipeline's configured dataset)")
    p.add_argument("--out", type=Path, default=Path("models/styles.npz"),
                   help="the model file to write (default: models/styles.npz)")
    p.add_argument("--joint-map", type=Path, default=None, metavar="FILE.yaml",
                   help="which joints make the 17 key points, for a skeleton no built-in family reads "
                        "(docs/formats.md §3.3); default: dataset.bvh.joint_map")
    p.add_argument("--alias", action="append", default=[], metavar="NAME=STYLE",
                   help="another name for a style, kept in the model (e.g. elderly=old); repeatable")
    p.add_argument("--neutral", default=None,
                   help="the style a motion of unknown style is read as (e.g. normal); default: "
                        "translation.neutral of params.yaml")
    p.add_argument("--views", default="front,side,three-quarter",
                   help="the camera views a folder of motion capture is learned in (comma-separated)")

    p = sub.add_parser("animate", help="your character performing your motion in a learned style")
    p.add_argument("--character", required=True,
                   help="AnimatedDrawings folder or char_cfg.yaml, RGBA PNG (+ --joints), joints YAML, "
                        "character JSON, or a built-in character name")
    p.add_argument("--joints", type=Path, default=None,
                   help="joints YAML (or nnsf.keypoints JSON) for a PNG character")
    p.add_argument("--motion", required=True,
                   help="a .bvh, a feature-matrix .csv, or synthetic:<character>/<motion>[/<frames>]")
    p.add_argument("--clip", default=None, help="the clip of a multi-clip CSV (default: the first)")
    p.add_argument("--style", default="none", help="a style of the model, or none (default)")
    p.add_argument("--source-style", default=None,
                   help="the style the motion is performed in, if the model knows it")
    p.add_argument("--model", type=Path, default=Path("models/styles.npz"),
                   help="a style model written by `nnsf styles` (default: models/styles.npz)")
    p.add_argument("--view", default="auto", help="front, side, three-quarter or auto (a BVH motion)")
    p.add_argument("--arms", default=None,
                   help="motion (the arms point as the motion's) or drawing (they swing about the pose they are "
                        "drawn in: arms drawn spread stay spread); default: the character YAML's, else motion")
    p.add_argument("--head", default=None,
                   help="motion (the head turns as the motion's) or torso (it keeps its drawn angle to the body: "
                        "for a drawing with no neck); default: the character YAML's, else motion")
    p.add_argument("--mask", default=None,
                   help="auto: a PNG without alpha, drawn on plain paper, gets its mask from the border colour")
    p.add_argument("--max-size", type=float, default=None, metavar="MP",
                   help="a drawing over this many megapixels is downscaled to it (default 4; 0: never)")
    p.add_argument("--out", type=Path, default=Path("animation.mp4"),
                   help="FILE.mp4, FILE.gif or a folder for PNG frames (a contact sheet is written beside)")
    p.add_argument("--fps", type=float, default=None, help="frames per second (default: the motion's)")
    p.add_argument("--vertices", type=int, default=800, help="mesh vertices (100..6000)")
    p.add_argument("--workers", type=int, default=None,
                   help="processes that render the frames (default: the CPUs available, at most 8)")
    p.add_argument("--joint-map", type=Path, default=None, metavar="FILE.yaml",
                   help="which joints of a BVH motion make the 17 key points (docs/formats.md §3.3)")
    p.add_argument("--keypoints", type=Path, default=None, metavar="FILE.csv",
                   help="also write the key points that drive the drawing (styled, in its pixels) as a "
                        "feature-matrix CSV (docs/formats.md §3.1)")

    p = sub.add_parser("bvh-info", help="what nnsf makes of a BVH file: hierarchy, family, key points, view")
    p.add_argument("file", type=Path, metavar="FILE.bvh")
    p.add_argument("--joint-map", type=Path, default=None, metavar="FILE.yaml",
                   help="which joints make the 17 key points (docs/formats.md §3.3), instead of detection")

    p = sub.add_parser("reshape-eval", help="reshaping evaluation on drawn characters (docs/method.md §15.7)")
    p.add_argument("--params", default="params.yaml", help=params_help)
    p.add_argument("--data", type=Path, required=True, nargs="+",
                   help="folders holding the drawings and motions reshape_eval names (each looked up in "
                        "the first folder that has it)")
    p.add_argument("--out", type=Path, default=Path("reports"))
    p.add_argument("--workers", type=int, default=1,
                   help="processes for the (drawing, motion) items (default 1; results are the same)")

    p = sub.add_parser("roto-real", help="the trackers on annotated real frames, scored against their silhouettes")
    p.add_argument("--params", default="params.yaml", help=params_help)
    p.add_argument("--data", type=Path, required=True,
                   help="frames: a folder of <character>/ folders of RGBA PNG frames; "
                        "lpc: a folder of LPC sprite sheets <body>.png")
    p.add_argument("--annotations", type=Path, required=True,
                   help="hand-made keyframe annotations, <character>.annotation.json (each one is tracked)")
    p.add_argument("--format", choices=("frames", "lpc"), default="frames",
                   help="how --data holds the frames (default: frames)")
    p.add_argument("--name", default=None,
                   help="the report's file stem (default: roto_<format>)")
    p.add_argument("--out", type=Path, default=Path("reports"))
    p.add_argument("--tol", type=float, default=None,
                   help="px from the silhouette boundary that counts as on it "
                        "(default 1.5 for frames, 1.0 for the 64-px LPC tiles)")
    return parser


def _print_metrics(command: str, metrics: dict) -> None:
    for key, value in metrics.items():
        print(f"{command}: {key} = {value:.6g}" if isinstance(value, float)
              else f"{command}: {key} = {value}")


def _max_size(args) -> dict:
    if args.max_size is None:
        return {}
    if not 0 <= args.max_size <= 100:
        raise InputError("--max-size", "max-size", "megapixels in 0..100 (0: never downscale)", args.max_size)
    return {"max_size": args.max_size}


def _animate(args) -> int:
    from nnsf.animate.animation import animate_files
    from nnsf.datasets.views import check_view

    check_view(args.view, "--view", "view")
    if args.fps is not None and not 1 <= args.fps <= 120:
        raise InputError("--fps", "fps", "a number 1..120", args.fps)
    if not 100 <= args.vertices <= 6000:
        raise InputError("--vertices", "vertices", "an integer 100..6000", args.vertices)
    joint_map = None
    if args.joint_map is not None:
        from nnsf.datasets.joint_map import read_joint_map

        joint_map = read_joint_map(args.joint_map)
    if args.keypoints is not None and args.keypoints.suffix.lower() != ".csv":
        raise InputError(args.keypoints, "--keypoints", "a .csv file name", args.keypoints.suffix or "none")
    _check_animate_paths(args)
    res = animate_files(args.character, args.motion, style=args.style, model=args.model, view=args.view,
                        out=args.out, fps=args.fps, joints=args.joints, source_style=args.source_style,
                        n_vertices=args.vertices, clip=args.clip, arms=args.arms, workers=args.workers,
                        head=args.head, joint_map=joint_map, keypoints=args.keypoints, mask=args.mask,
                        **_max_size(args))
    # The notes were said before rendering (animate_files, progress on).
    parts = ", ".join(f"{k} {v:.2f} s" for k, v in res.seconds.items() if k != "total")
    print(f"animate: {res.frames} frames at {res.fps:g} fps in {res.seconds['total']:.2f} s ({parts})")
    for kind, path in res.files.items():
        print(f"animate: {kind}: {path}" + (" (H.264)" if kind == "mp4" else ""))
    if args.keypoints is not None:
        print(f"animate: keypoints: {args.keypoints}")
    return 0


def _check_animate_paths(args) -> None:
    """Before any work: every output of ``nnsf animate`` can be written where it is named, and none
    of them is (or, for a folder of frames, holds) one of the command's input files.

    An output file may not be an existing folder; a frames folder must be new, empty or an
    earlier run's frames (:func:`nnsf.reshape.video.check_frames_folder`: it is replaced whole);
    two outputs may not share a path (``--keypoints`` onto the video would leave one of them).
    """
    from nnsf.animate.animation import output_targets
    from nnsf.names import real
    from nnsf.reshape.video import check_frames_folder

    outputs = {("--out (its contact sheet)" if kind == "sheet" else "--out"): (Path(path), kind)
               for kind, path in output_targets(args.out).items()}
    if args.keypoints is not None:
        outputs["--keypoints"] = (Path(args.keypoints), "csv")
    inputs = {"--motion": args.motion, "--character": args.character, "--joints": args.joints,
              "--model": args.model if str(args.style).strip().lower() != "none" else None,
              "--joint-map": args.joint_map}
    inputs = {k: real(v) for k, v in inputs.items() if v is not None and Path(v).exists()}
    taken: dict[Path, str] = {}
    for field, (path, kind) in outputs.items():
        if kind == "png":
            check_frames_folder(path, field=field)
        elif path.is_dir():
            raise InputError(path, field, f"a {kind.upper()} file name (a folder is in the way)")
        where = real(path)
        for name, given in inputs.items():
            if where == given or (kind == "png" and given.is_relative_to(where)):
                raise InputError(path, field, f"an output path apart from the {name} input", str(given))
        if where in taken:
            raise InputError(path, field, f"a path of its own ({taken[where]} names it too)")
        taken[where] = field


#: Lines of one kind (``skipped``, ``skipped label``, ``note``, ``warning``) of a reader's report
#: printed; the rest are counted in one line.
MAX_REPORT_LINES = 20


def capped(report: list[str], per_kind: int = MAX_REPORT_LINES) -> list[str]:
    """``report`` with at most ``per_kind`` lines of each kind (the text before its first ``:``);
    the others become one line ``<kind>: N more not shown``, so a folder of ten thousand
    unreadable files is twenty lines and a count, not ten thousand lines."""
    shown: list[str] = []
    hidden: dict[str, int] = {}
    for line in report:
        kind = line.split(":", 1)[0]
        if sum(1 for s in shown if s.split(":", 1)[0] == kind) < per_kind:
            shown.append(line)
        else:
            hidden[kind] = hidden.get(kind, 0) + 1
    return shown + [f"{kind}: {n} more not shown" for kind, n in hidden.items()]


def _bvh_info(args) -> int:
    from nnsf.datasets.bvh_info import bvh_info

    joint_map = None
    if args.joint_map is not None:
        from nnsf.datasets.joint_map import read_joint_map

        joint_map = read_joint_map(args.joint_map)
    info = bvh_info(args.file, joint_map=joint_map)
    print("\n".join(info.lines), flush=True)
    if info.error is not None:
        raise info.error
    return 0


def _styles_params(args):
    """The params ``nnsf styles`` runs with: ``--params``, else ./params.yaml, else the package defaults."""
    from nnsf import params as params_mod

    if args.params is not None or Path("params.yaml").is_file():
        return params_mod.load(args.params or "params.yaml")
    params = params_mod.load_defaults()
    # Said with the reader's report once the model is written (a failure stays one line).
    params.note = (f"no params.yaml in {Path.cwd()}; used the package defaults ({params.source}); "
                   "--params FILE picks another")
    return params


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    old = None
    if threading.current_thread() is threading.main_thread():
        old = signal.signal(signal.SIGTERM, terminate_as_interrupt)
    try:
        return _quiet_warnings(_run, args)
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)


#: Warnings repeated on stderr after a command that succeeded (one line each).
MAX_WARNINGS_SHOWN = 5


def _quiet_warnings(run, args) -> int:
    """``run(args)`` with Python warnings (numpy's overflow, a library's deprecation) kept off the
    error path: a failure is its one ``error:`` line alone; after a success each distinct warning
    is one ``nnsf: warning:`` line (at most :data:`MAX_WARNINGS_SHOWN`)."""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        code = run(args)
    if code == 0:
        seen = list(dict.fromkeys(f"{w.category.__name__}: {one_line(w.message, 300)}" for w in caught))
        for text in seen[:MAX_WARNINGS_SHOWN]:
            print(f"nnsf: warning: {text}", file=sys.stderr)
        if len(seen) > MAX_WARNINGS_SHOWN:
            print(f"nnsf: warning: {len(seen) - MAX_WARNINGS_SHOWN} more not shown", file=sys.stderr)
    return code


def _run(args) -> int:
    """The command ``args`` names; an exit status, one line on stderr for a failure."""
    try:
        _settle_publications()
        if args.command == "animate":  # needs no params.yaml
            return _animate(args)
        if args.command == "bvh-info":
            return _bvh_info(args)
        from nnsf import params as params_mod
        from nnsf import pipeline, stages

        params = _styles_params(args) if args.command == "styles" else params_mod.load(args.params)
        if args.command == "check":
            _check_stage_params(params)
            print(f"{args.params}: ok")
            return 0
        # Every output folder is checked before any work: a file in the way, no
        # permission or a read-only disk fails here in one line, and nothing is written.
        if args.command in ("translate", "reshape"):
            pipeline.check_outputs(args.command, [args.out])
            # The folder is swapped in whole: never one that holds the user's own files.
            marker = {"translate": "translation.json", "reshape": "metrics.json"}[args.command]
            check_replaceable(args.out, "--out", f"an earlier `nnsf {args.command}` output ({marker})",
                              marker=marker)
        elif args.command in ("reshape-eval", "roto-real"):
            pipeline.check_outputs(args.command, [args.out, args.out / "figures"])
        elif args.command == "styles":
            pipeline.check_outputs(args.command, [Path(args.out).parent])
            if Path(args.out).suffix.lower() != ".npz" or Path(args.out).is_dir():
                raise InputError(args.out, "--out", "a .npz file name for the model (not a folder)",
                                 Path(args.out).suffix or "no extension")
        elif args.command != "sweep":  # `nnsf sweep` writes its table to stdout only
            pipeline.check_outputs(args.command)
            if args.command == "roto" and args.export_cvat is not None:
                pipeline.check_outputs(args.command, [args.export_cvat])
        if args.command == "sweep":
            import pandas as pd

            rows = []
            for point in stages.sweep_grid(params):
                res = stages.sweep_point(params, point)
                rows.append({**point, **res.metrics})
                print(f"alpha={point['alpha']:g} beta={point['beta']:g} rank={point['rank']}: "
                      f"precision {res.metrics['precision_mean']:.3f}", file=sys.stderr)
            pd.DataFrame(rows).to_csv(sys.stdout, index=False)
            return 0
        if args.command == "translate":
            result = stages.translate(params, features_csv=args.features, out_dir=args.out,
                                      content_clip=args.clip, style=args.style)
            print(f"translate: wrote {args.out}/ ({result.params['content_clip']} as "
                  f"{result.params['style']}); open {args.out / 'translation.gif'}")
        elif args.command == "reshape":
            if args.clip is not None:
                params.setdefault("reshape", {})["clip"] = args.clip
            character_path = None
            if args.joints is not None and (args.character is None or not Path(args.character).exists()):
                raise InputError("--joints", "--character", "an existing PNG drawing the joints belong to",
                                 args.character)
            if args.character is not None:
                if Path(args.character).exists():
                    character_path = Path(args.character)
                else:
                    params.setdefault("reshape", {})["character"] = args.character
            result = stages.reshape(params, motion_csv=args.motion, out_dir=args.out,
                                    character_path=character_path, joints=args.joints)
            shown = [str(a) for a in result.artifacts if str(a).endswith(".gif")]
            for note in read_json(Path(args.out) / "metrics.json", RESHAPE_NOTES).get("notes", []):
                print(f"reshape: note: {note}", file=sys.stderr)
            print(f"reshape: wrote {args.out}/" + (f"; open {shown[0]}" if shown else ""))
        elif args.command == "styles":
            from nnsf.factor.stage import styles_by_hand
            from nnsf.factor.style_names import check_alias_name

            aliases = {}
            for text in args.alias:
                name, sep, style = text.partition("=")
                if not sep or not name.strip() or not style.strip():
                    raise InputError("--alias", "alias", "NAME=STYLE, e.g. elderly=old", text)
                check_alias_name(name.strip(), "--alias", "alias")
                same = [a for a in aliases if a.casefold() == name.strip().casefold()]
                if same:
                    raise InputError("--alias", name.strip(), "each alias once (letter case ignored)",
                                     f"{same[0]}={aliases[same[0]]} and {text}")
                aliases[name.strip()] = style.strip()
            if args.neutral is not None:
                params["translation"] = {**params.get("translation", {}), "neutral": args.neutral}
            result, report = styles_by_hand(params, args.data, args.out, joint_map=args.joint_map,
                                            aliases=aliases, views=tuple(v for v in args.views.split(",") if v))
            for line in ([params.note] if getattr(params, "note", None) else []) + capped(report):
                print(f"styles: {line}", file=sys.stderr)
            print(f"styles: wrote {args.out} ({result.metrics['styles']} styles, "
                  f"{result.metrics['contents']} contents, "
                  f"{result.metrics.get('views', 1)} view(s))")
        elif args.command == "reshape-eval":
            from nnsf.reshape.evaluation import reshape_eval

            for folder in args.data:
                if not folder.is_dir():
                    raise InputError(folder, "--data", "a data folder holding the drawings and motions "
                                     "reshape_eval names")
            if args.workers < 1:
                raise InputError("nnsf reshape-eval", "--workers", "1 or more", args.workers)
            mapper = None
            if args.workers > 1:
                from concurrent.futures import ProcessPoolExecutor

                def mapper(fn, xs):
                    with ProcessPoolExecutor(args.workers) as ex:
                        return list(ex.map(fn, xs))
            result = reshape_eval(params, data_root=args.data, out_dir=args.out, mapper=mapper)
        elif args.command == "roto-real":
            from nnsf.roto import lpc, real
            from nnsf.roto.options import track_options

            report, tol = ((lpc.lpc_report, lpc.TOL) if args.format == "lpc"
                           else (real.frames_report, real.TOL))
            args.tol = tol if args.tol is None else args.tol
            stem = args.name or f"roto_{args.format}"
            if not stem.replace("_", "").replace("-", "").isalnum():
                raise InputError("nnsf roto-real", "--name", "a file stem of letters, digits, - and _", stem)
            summary = report(args.data, args.annotations, args.out, stem=stem, tol=args.tol,
                             **track_options(params))
            for tracker, score in summary["trackers"].items():
                extra = ""
                if tracker in summary.get("coverage", {}):
                    extra = (f"; coverage {summary['coverage'][tracker]:.3f}, length ratio "
                             f"{summary['length_ratio'][tracker]:.3f}")
                print(f"roto-real: {tracker} = {score:.3f} of outline samples within {args.tol:g} px "
                      f"of the silhouette{extra}")
            if summary.get("snap"):
                print("roto-real: ours ended with snap " + ", ".join(
                    f"{c} {t}" for c, t in sorted(summary["snap"].items())))
            print(f"roto-real: keyframe ceiling = {summary['ceiling']:.3f}; "
                  f"wrote {args.out / (stem + '.json')}")
            return 0
        elif args.command == "roto" and (args.corrections or args.export_cvat):
            from nnsf.roto.correct import apply_corrections, export_clips

            if args.corrections is not None:
                done = apply_corrections(params, args.corrections, pipeline.FRAMES_DIR,
                                         pipeline.TRACKS_DIR, clip=args.clip)
                if not done["corrected_frames"]:
                    print(f"track: {done['clip']}: no frame of {args.corrections} differs from the tracked "
                          "curves (at the file's precision) and no frame was ticked nnsf_keyframe: nothing "
                          "to re-track")
                print(f"track: {done['clip']}: corrected frames {done['corrected_frames']}; "
                      f"re-tracked intervals {done['resolved_intervals']}; wrote {done['curves']}")
                from nnsf.roto.stage import keypoints_from_tracks

                result = keypoints_from_tracks(params, frames_dir=pipeline.FRAMES_DIR,
                                               tracks_dir=pipeline.TRACKS_DIR,
                                               out_dir=pipeline.TRACKED_DIR)
            else:
                result = stages.roto(params)
            if args.export_cvat is not None:
                out = export_clips(pipeline.FRAMES_DIR, pipeline.TRACKS_DIR, args.export_cvat)
                print(f"track: wrote {len(out)} CVAT for video 1.1 files to {args.export_cvat}/")
        else:
            result = stages.get(args.command)(params)
        _print_metrics(args.command, result.metrics)
        return 0
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except OSError as err:
        if err.errno not in UNWRITABLE:
            return _unexpected(args.command, err)
        # A file the stage could not write (the folder check ran first, so the disk
        # became full or read-only, or a permission changed, while it worked).
        print(f"error: {err.filename or args.command}: {err.strerror}", file=sys.stderr)
        return 2
    except Exception as err:  # a bug or an environment problem
        return _unexpected(args.command, err)


def _check_stage_params(params: dict) -> None:
    """The parameter checks stages make beyond the schema that need no data, for ``nnsf check``.

    The schema (:func:`nnsf.params.load`) has every field's type and range;
    these combine fields or compare them with the code (motion names the
    generator has, a translator's settings that go together, subkeys the
    reshaping method needs).  Each runs when its section is present, so
    ``nnsf check`` refuses what the stage would.
    """
    from nnsf.factor.style_model import check_translator, translator_params
    from nnsf.frames.stage import frames_params
    from nnsf.reshape.stage import stage_params as reshape_params

    if "frames" in params:
        frames_params(params)
    if "reshape" in params:
        reshape_params(params)
    if "translation" in params:
        check_translator(params, translator_params(params), params["translation"].get("synthesis"))
    joint_map = params.get("dataset", {}).get("bvh", {}).get("joint_map") if isinstance(
        params.get("dataset"), dict) and isinstance(params["dataset"].get("bvh"), dict) else None
    if joint_map is not None:
        from nnsf.datasets.joint_map import read_joint_map

        read_joint_map(joint_map)           # what the data stage reads (a missing or bad map: one line)


def _settle_publications() -> None:
    """Finish or drop the output sets a killed stage left half-published under ``reports/``.

    Every command does this first (:func:`nnsf.publish.recover_all`), so a set
    interrupted by a kill is the old or the new one again before anything reads it.
    """
    from nnsf.publish import recover_all

    for note in recover_all():
        print(f"nnsf: note: {note}", file=sys.stderr)


def _unexpected(command: str, err: BaseException) -> int:
    """A bug or an environment problem: one line (the traceback with ``NNSF_DEBUG=1``), exit 1."""
    if os.environ.get("NNSF_DEBUG"):
        raise err
    print(f"error: {command}: {exception_line(err)} (set NNSF_DEBUG=1 for the traceback)", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main())
