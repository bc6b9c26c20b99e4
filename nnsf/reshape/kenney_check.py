"""Real-frame check on Kenney's "Toon Characters": deform ``idle`` to the poses of ``walk0..7``.

The ``idle`` drawing (:func:`nnsf.reshape.kenney.kenney_character`) is
deformed so its key points go to each walk frame's annotated key points
(same pixel grid, no retargeting), rendered, and its silhouette (alpha ≥
128) is compared with the real walk frame's (alpha > 0) by IoU.  The
identity baseline is the IoU of the undeformed idle silhouette with the
walk frame's: the number the deformation has to beat.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nnsf.reshape.kenney import WALK, _frame, kenney_character, read_keypoint_file
from nnsf.reshape.render import MeshRenderer
from nnsf.reshape.stage import build_rig


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks."""
    u = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / u) if u else float("nan")


def check_character(name: str, image_root, annotation_dir, n_vertices: int = 300,
                    variants=(("layered", "ours"), ("layered", "keypoints"), ("limbs", "ours"), ("limbs", "keypoints"),
                              ("connected", "keypoints"))) -> list[dict]:
    """IoU rows (one per walk frame and variant, plus the identity baseline) for one character."""
    ch, moves = kenney_character(name, image_root, annotation_dir)
    ann = Path(annotation_dir) / f"{name}.keypoints.json"
    folder = Path(image_root) / name
    kps = read_keypoint_file(ann)
    walks = [_frame(folder, kps, w, ann) for w in WALK]
    targets = np.stack([kps[n] for n, _ in walks])
    truth = [img[..., 3] > 0 for _, img in walks]
    mask = ch.mask
    rows = [{"character": name, "frame": w, "variant": "identity", "iou": iou(mask, t)}
            for w, t in zip(WALK, truth)]
    for mesh, method in variants:
        rig = build_rig(ch, method=method, mesh=mesh, n_vertices=n_vertices)
        V = rig.animate(targets)
        r = MeshRenderer.for_mesh(rig.mesh, ch)
        for w, t, v in zip(WALK, truth, V):
            sil = r.render(v)[..., 3] >= 128
            rows.append({"character": name, "frame": w, "variant": f"{mesh}/{method}", "iou": iou(sil, t)})
    for r_ in rows:
        r_["snapped_px"] = float(moves.max())
    return rows
