"""Reading a frame set: its ``index.csv`` and each clip's frame images, with clear errors for bad folders and files."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from nnsf.errors import InputError
from nnsf.frames.annotation import Annotation, check_relative, read_annotation
from nnsf.io import PNG_SIGNATURE, decode_image, png_header, read_npz
from nnsf.names import safe_name
from nnsf.schema import Array

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".webp")

#: The arrays of a rendered clip's ``truth.npz`` (:func:`nnsf.frames.render.render_clip`; T frames,
#: C side curves of S samples, P control points, an H x W canvas): what :func:`read_truth` accepts.
TRUTH = {
    "keypoints": Array("f", ("T", 17, 2)),
    "sides": Array("f", ("T", "C", "S", 2)),
    "side_names": Array("U", ("C",)),
    "control": Array("f", ("T", "C", "P", 2)),
    "fit_error": Array("f", ("T", "C")),
    "visible": Array("b", ("T", "C", "S")),
    "draw_order": Array("U", (None,)),
    "alpha": Array("u", ("T", "H", "W")),
    "size": Array("iu", ()),
}


def read_truth(folder) -> dict[str, np.ndarray]:
    """A rendered clip's ground truth ``<folder>/truth.npz``, checked against :data:`TRUTH`."""
    return read_npz(Path(folder) / "truth.npz", TRUTH, what="file of a rendered clip's ground truth")


def _decode(path: Path, source, field_name: str, size: tuple[int, int] | None = None,
            size_from: str = "the clip's image size") -> np.ndarray:
    """Decode one frame file to RGB uint8 ``(H, W, 3)``; InputError on a bad file.

    A PNG's header is checked first (:func:`nnsf.io.png_header`: complete,
    undamaged, and ``size`` = (width, height) when given), so a truncated
    frame or one claiming a huge size is refused before it is decoded, and
    the decoder's messages never reach stderr (:func:`nnsf.io.decode_image`).
    """
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(path, field_name, "a readable image file", reason=str(exc)) from None
    if size is not None and data.startswith(PNG_SIGNATURE):
        got = png_header(data, path, field_name)
        if got != tuple(size):
            raise _size_error(path, size, got, size_from)
    img = decode_image(data, path, field_name)
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    if img.shape[2] == 4:
        # Transparent pixels composite over white, as a viewer shows them.
        rgb = img[..., :3].astype(np.float32)
        a = img[..., 3:4].astype(np.float32) / 255.0
        img = np.rint(rgb * a + 255.0 * (1 - a)).astype(np.uint8)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _size_error(path: Path, want, got, size_from: str) -> InputError:
    return InputError(path, "image size", f"{want[0]}x{want[1]} px (width x height), {size_from}; "
                      "every frame of a clip must have the same size", f"{got[0]}x{got[1]}")


def frame_paths(folder, annotation: Annotation | None = None) -> list[Path]:
    """The frame files of a clip, in order, checked to exist inside ``folder``.

    With an annotation, its ``frames`` list (relative paths); without one,
    every image file in ``folder`` sorted by name.  Raises InputError for a
    missing or empty folder, a path leaving the folder and a missing frame.
    """
    folder = Path(folder)
    source = annotation.source if annotation is not None else folder
    if not folder.is_dir():
        raise InputError(folder, "folder", "an existing clip folder of frame images")
    images = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not images:
        raise InputError(folder, "frames", "a clip folder holding frame images (.png, .jpg, ...)",
                         "an empty folder" if not any(folder.iterdir()) else "no image files")
    if annotation is None:
        return images
    root = folder.resolve()
    paths = []
    for i, rel in enumerate(annotation.frames):
        check_relative(rel, source, f"frames[{i}]")
        p = (folder / rel)
        if not p.resolve().is_relative_to(root):
            raise InputError(source, f"frames[{i}]", "a path that stays inside the clip's folder "
                             "(symbolic links included)", rel)
        if not p.is_file():
            raise InputError(source, f"frames[{i}]", f"an existing frame file in {folder}",
                             f"{rel!r} does not exist")
        paths.append(p)
    return paths


def read_clip(folder, annotation: Annotation | str | Path | None = None) -> np.ndarray:
    """Read a clip's frames: ``(T, H, W, 3)`` uint8 RGB.

    ``annotation``: an :class:`Annotation`, the path of its JSON file, or None
    (every image in ``folder`` by name).  Frames must all have one size, and
    the annotation's ``image_size`` when given.  Every failure is an
    :class:`InputError` naming the file: missing or empty folder, frame
    listed but absent, path leaving the folder, unreadable or truncated
    image, frames of different sizes.
    """
    if isinstance(annotation, (str, Path)):
        annotation = read_annotation(annotation)
    paths = frame_paths(folder, annotation)
    frames = []
    want = tuple(annotation.image_size) if annotation is not None else None   # (w, h)
    what = "the annotation's image_size" if annotation is not None else f"the size of {paths[0].name}"
    for i, p in enumerate(paths):
        img = _decode(p, annotation.source if annotation else folder, f"frames[{i}]", want, what)
        got = (img.shape[1], img.shape[0])
        if want is None:
            want = got
        elif got != want:
            raise _size_error(p, want, got, what)
        frames.append(img)
    return np.stack(frames)


#: Columns of a frame set's ``index.csv``.
INDEX_COLUMNS = ("clip", "character", "motion", "folder", "frames")


def read_index(frames_dir) -> pd.DataFrame:
    """``<frames_dir>/index.csv`` checked: columns, unique clips, each clip id a safe file name
    (:func:`nnsf.names.safe_name`), folders inside ``frames_dir`` once symbolic links are resolved."""
    path = Path(frames_dir) / "index.csv"
    if not path.is_file():
        raise InputError(path, "file", "the frame-set index written by the render_frames stage")
    try:
        index = pd.read_csv(path, dtype=str, keep_default_na=False)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, OSError) as exc:
        raise InputError(path, "file", "a readable CSV table", reason=str(exc)) from None
    missing = [c for c in ("clip", "folder") if c not in index.columns]
    if missing:
        raise InputError(path, missing[0], "columns " + ", ".join(INDEX_COLUMNS))
    if index.empty:
        raise InputError(path, "rows", "at least one clip")
    dup = index["clip"].duplicated()
    if dup.any():
        raise InputError(path, "clip", "each clip once", index["clip"][dup].iloc[0])
    root = Path(frames_dir).resolve()
    for i, (clip, f) in enumerate(zip(index["clip"], index["folder"])):
        # A clip id names the stages' output files (<tracks>/<clip>/curves.npz, <clip>.xml).
        safe_name(clip, path, f"clip (row {i + 1})")
        check_relative(f, path, f"folder (row {i + 1})")
        if not (Path(frames_dir) / f).resolve().is_relative_to(root):
            raise InputError(path, f"folder (row {i + 1})", "a folder inside the frame set "
                             "(symbolic links resolved)", f)
    return index
