"""Render the synthetic dataset as flat cartoon frames with exact contour ground truth.

Every body part is a filled shape with a dark outline in the character's flat
palette (:class:`nnsf.datasets.synthetic_characters.Palette`): torso in
``body``, limbs in ``limbs`` (far-side limbs 22 % darker), head in ``head``,
outlines in ``outline``, on a plain pale background.

Shapes (widths are the character's ``arm_width``, ``leg_width``,
``torso_width`` and ``head_radius``, scaled by ``size / 256``):

* a **limb** is a ribbon along its bone p_start → p_end, tapering from the
  start width to the end width with a slight bulge (``w(u) = w0 + (w1 − w0) u
  + k w0 sin(πu)``), closed by half-disc caps at both joints;
* the **torso** is a ribbon of the same kind along the quadratic curve
  thorax → spine → pelvis (so it bends with the hunch), with a slight waist;
* the **head** is an ellipse centred midway between neck and head top, its
  axis along them, half-axes ``(|d|/2) / cos 35°`` and ``head_radius``.

The two long edges of a ribbon, and the two ellipse arcs between the neck and
head-top ends (angles 35°..145° from the neck end), are the ground-truth side
contours ``<group>.a`` (on the +R90·d side, R90 = :func:`nnsf.reshape.limbs.rot90`)
and ``<group>.b``.  The outline stroke is centred on them, so the true contour
runs along the middle of the dark line.  Side-contour ends lie symmetric
about the joints, so the true ω of Eq. 2-3 is 0.5 for every limb end.

Drawing order (painter's, back to front) is :data:`DRAW_ORDER`: the character
faces +x in a three-quarter view with its right side towards the viewer
(right hip and shoulder at smaller x), so its **left** limbs are the far side
and go behind the torso, its **right** limbs in front of torso and head; in
each chain the upper segment first, so the lower one overlaps the joint.

Pixel convention: the centre of the top-left pixel is (0, 0).  Frames are
drawn at :data:`SUPERSAMPLE` times the size with OpenCV's non-anti-aliased
fills (sub-pixel vertex precision) and reduced with area averaging, which
anti-aliases deterministically: the same arguments give byte-identical PNGs.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from nnsf.datasets.synthetic import (
    CANVAS, CHANNELS, REST, CharacterSpec, character, clip_points, forward_kinematics,
)
from nnsf.datasets.synthetic_motions import ANGLE_CHANNELS
from nnsf.frames.annotation import Annotation, Keyframe, write_annotation
from nnsf.frames.curves import (
    GROUP_JOINTS, GROUPS, SIDE_NAMES, fit_control_points,
)
from nnsf.io import atomic_path, write_npz
from nnsf.skeleton.layout import JOINT_INDEX, JOINTS

#: Groups back to front (see the module docstring).
DRAW_ORDER: tuple[str, ...] = (
    "l_upper_arm", "l_forearm", "l_thigh", "l_shin", "torso", "head",
    "r_thigh", "r_shin", "r_upper_arm", "r_forearm",
)
#: Background colour (RGB).
BACKGROUND = (238, 234, 224)
#: Far-side (left) limbs are drawn in the limb colour times this.
FAR_SHADE = 0.78
#: Drawing resolution factor (anti-aliasing by area averaging).
SUPERSAMPLE = 4
#: Samples per side contour in the ground truth.
SIDE_SAMPLES = 64
#: Control points per side curve in annotations and ``truth.npz``.
CONTROL_POINTS = 5
#: Half-opening of the head's side arcs, measured from the bone axis (degrees).
HEAD_ARC_DEG = 35.0

# Width profile per group: (start width, end width, bulge) as multiples of the
# group's base width.
_PROFILE = {
    "upper_arm": (1.0, 0.8, 0.10), "forearm": (0.8, 0.62, 0.08),
    "thigh": (1.0, 0.8, 0.10), "shin": (0.8, 0.6, 0.08),
    "torso": (1.0, 0.9, -0.08),
}
_SHIFT = 4                       # fixed-point fraction bits for OpenCV vertices
_CAP = 10                        # samples per half-disc cap


def _rot90(v: np.ndarray) -> np.ndarray:
    # Same convention as nnsf.reshape.limbs.rot90 (not imported: that module
    # pulls in the whole reshaping stack).
    return np.stack([-v[..., 1], v[..., 0]], axis=-1)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _widths(group: str, spec: CharacterSpec, scale: float) -> tuple[float, float, float]:
    P = spec.proportions
    if group == "torso":
        base, kind = P.torso_width, "torso"
    else:
        kind = group.split("_", 1)[1]
        base = P.arm_width if kind in ("upper_arm", "forearm") else P.leg_width
    w0, w1, k = _PROFILE[kind]
    return base * w0 * scale, base * w1 * scale, base * k * scale


def _ribbon(center: np.ndarray, tangent: np.ndarray, width: np.ndarray):
    """Sides and outline of a capped ribbon.

    center, tangent ``(T, S, 2)``; width ``(S,)`` full widths.  Returns
    ``a, b`` ``(T, S, 2)`` and the closed outline polygon ``(T, 2S + 2·_CAP, 2)``.
    """
    n = _rot90(tangent)
    half = 0.5 * width[None, :, None]
    a, b = center + half * n, center - half * n
    th = np.linspace(0.0, np.pi, _CAP + 2)[1:-1, None]            # cap interior angles
    c1, t1, n1, r1 = center[:, -1:], tangent[:, -1:], n[:, -1:], half[:, -1:]
    end_cap = c1 + r1 * (np.cos(th) * n1 + np.sin(th) * t1)      # a[-1] -> b[-1] around the end
    c0, t0, n0, r0 = center[:, :1], tangent[:, :1], n[:, :1], half[:, :1]
    start_cap = c0 - r0 * (np.cos(th) * n0 + np.sin(th) * t0)    # b[0] -> a[0] around the start
    poly = np.concatenate([a, end_cap, b[:, ::-1], start_cap], axis=1)
    return a, b, poly


def body_geometry(keypoints: np.ndarray, spec: CharacterSpec, size: int,
                  n_samples: int = SIDE_SAMPLES) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Side contours and outline polygons of a posed character.

    keypoints ``(T, 17, 2)`` px on a ``size``-px canvas.  Returns ``sides``
    ``(T, 20, n_samples, 2)`` in :data:`SIDE_NAMES` order and ``{group:
    polygon (T, K, 2)}`` closed outlines to fill.
    """
    kp = np.asarray(keypoints, dtype=np.float64)
    T = kp.shape[0]
    scale = size / 256.0
    u = np.linspace(0.0, 1.0, n_samples)
    sides = np.empty((T, len(SIDE_NAMES), n_samples, 2))
    polys: dict[str, np.ndarray] = {}
    for gi, g in enumerate(GROUPS):
        s, e = GROUP_JOINTS[g]
        p0, p1 = kp[:, s], kp[:, e]
        if g == "head":
            d = p1 - p0
            half_len = 0.5 * np.linalg.norm(d, axis=-1)[:, None, None]
            ax, nx = _unit(d)[:, None], _rot90(_unit(d))[:, None]
            c = 0.5 * (p0 + p1)[:, None]
            beta = np.deg2rad(HEAD_ARC_DEG)
            A = half_len / np.cos(beta)
            R = spec.proportions.head_radius * scale
            phi = np.linspace(beta, np.pi - beta, n_samples)[None, :, None]
            along = -A * np.cos(phi)
            a, b = c + along * ax + R * np.sin(phi) * nx, c + along * ax - R * np.sin(phi) * nx
            full = np.linspace(0.0, 2 * np.pi, 4 * n_samples, endpoint=False)[None, :, None]
            poly = c - A * np.cos(full) * ax + R * np.sin(full) * nx
        else:
            w0, w1, k = _widths(g, spec, scale)
            width = w0 + (w1 - w0) * u + k * np.sin(np.pi * u)
            if g == "torso":
                # Quadratic through thorax (u=0), spine (u=1/2), pelvis (u=1).
                m = 2.0 * kp[:, JOINT_INDEX["spine"]] - 0.5 * (p0 + p1)
                uu = u[None, :, None]
                center = ((1 - uu) ** 2 * p0[:, None] + 2 * uu * (1 - uu) * m[:, None]
                          + uu ** 2 * p1[:, None])
                tangent = _unit(2 * (1 - uu) * (m - p0)[:, None] + 2 * uu * (p1 - m)[:, None])
            else:
                center = p0[:, None] + u[None, :, None] * (p1 - p0)[:, None]
                tangent = np.broadcast_to(_unit(p1 - p0)[:, None], center.shape)
            a, b, poly = _ribbon(center, tangent, width)
        sides[:, 2 * gi], sides[:, 2 * gi + 1] = a, b
        polys[g] = poly
    return sides, polys


def _colours(spec: CharacterSpec) -> dict[str, tuple[int, int, int]]:
    pal = spec.palette
    far = tuple(int(round(c * FAR_SHADE)) for c in pal.limbs)
    out = {"torso": tuple(pal.body), "head": tuple(pal.head)}
    for g in GROUPS[:8]:
        out[g] = far if g.startswith("l_") else tuple(pal.limbs)
    return out


def _fixed(poly: np.ndarray, factor: int) -> np.ndarray:
    """px (pixel centres at integers) -> OpenCV fixed-point vertices at ``factor`` x resolution."""
    hr = (poly + 0.5) * factor - 0.5
    return np.rint(hr * (1 << _SHIFT)).astype(np.int32)


def draw_frames(polys: dict[str, np.ndarray], spec: CharacterSpec, size: int,
                background=BACKGROUND) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Paint every frame.

    Returns ``rgb`` ``(T, size, size, 3)`` uint8, ``alpha`` ``(T, size, size)``
    uint8 coverage of the character, and ``labels`` ``(T, size, size)`` int8:
    the index into :data:`GROUPS` of the part seen at each pixel (-1: none),
    drawn without anti-aliasing at the frame's own resolution.
    """
    ss = SUPERSAMPLE
    T = next(iter(polys.values())).shape[0]
    colours = _colours(spec)
    outline = tuple(int(c) for c in spec.palette.outline)
    scale = size / 256.0
    thick_hr = max(1, int(round(spec.proportions.outline * scale * ss)))
    thick_lr = max(1, int(round(spec.proportions.outline * scale)))
    rgb = np.empty((T, size, size, 3), np.uint8)
    alpha = np.empty((T, size, size), np.uint8)
    labels = np.empty((T, size, size), np.int8)
    hr = np.empty((size * ss, size * ss, 3), np.uint8)
    cover = np.empty((size * ss, size * ss), np.uint8)
    lab = np.empty((size, size), np.uint8)
    for t in range(T):
        hr[:] = background
        cover[:] = 0
        lab[:] = 255
        for g in DRAW_ORDER:
            pts = [_fixed(polys[g][t], ss)]
            cv2.fillPoly(hr, pts, colours[g], cv2.LINE_8, _SHIFT)
            cv2.polylines(hr, pts, True, outline, thick_hr, cv2.LINE_8, _SHIFT)
            cv2.fillPoly(cover, pts, 255, cv2.LINE_8, _SHIFT)
            cv2.polylines(cover, pts, True, 255, thick_hr, cv2.LINE_8, _SHIFT)
            lo = [_fixed(polys[g][t], 1)]
            gi = GROUPS.index(g)
            cv2.fillPoly(lab, lo, gi, cv2.LINE_8, _SHIFT)
            cv2.polylines(lab, lo, True, gi, thick_lr, cv2.LINE_8, _SHIFT)
        rgb[t] = cv2.resize(hr, (size, size), interpolation=cv2.INTER_AREA)
        alpha[t] = cv2.resize(cover, (size, size), interpolation=cv2.INTER_AREA)
        labels[t] = np.where(lab == 255, -1, lab).astype(np.int8)
    return rgb, alpha, labels


def visibility(sides: np.ndarray, labels: np.ndarray, inset: float = 1.5) -> np.ndarray:
    """Whether each side sample is seen: ``(T, 20, S)`` bool.

    A sample counts as visible when the pixel ``inset`` px inside its part
    (towards the opposite side curve) shows that part in ``labels``
    (:func:`draw_frames`), i.e. no part drawn later covers it.
    """
    T, C, S, _ = sides.shape
    other = sides.reshape(T, C // 2, 2, S, 2)[:, :, ::-1].reshape(T, C, S, 2)
    probe = sides + inset * _unit(other - sides)
    ij = np.rint(probe).astype(np.int64)
    h, w = labels.shape[1:]
    inside = (ij[..., 0] >= 0) & (ij[..., 0] < w) & (ij[..., 1] >= 0) & (ij[..., 1] < h)
    x, y = np.clip(ij[..., 0], 0, w - 1), np.clip(ij[..., 1], 0, h - 1)
    seen = labels[np.arange(T)[:, None, None], y, x]
    own = (np.arange(C) // 2)[None, :, None]
    return inside & (seen == own)


def keyframe_indices(n_frames: int, every: int) -> list[int]:
    """First and last frame, plus every ``every``-th (0: only first and last)."""
    ks = {0, n_frames - 1}
    if every > 0:
        ks.update(range(0, n_frames, every))
    return sorted(ks)


def frame_name(t: int) -> str:
    return f"frame_{t:04d}.png"


def render_clip(folder, character_name: str, motion_name: str, n_frames: int,
                variation: int = 0, seed: int = 0, size: int = 256, keyframe_every: int = 0,
                control_points: int = CONTROL_POINTS, clip: str | None = None) -> dict:
    """Render one synthetic clip into ``folder`` (created; files written atomically).

    Writes ``frame_0000.png`` … (RGB), ``truth.npz`` and ``annotation.json``
    (keyframes :func:`keyframe_indices`, control points fitted to the true
    sides, calibration points, true key points).  ``truth.npz`` holds
    ``keypoints`` (T, 17, 2), ``sides`` (T, 20, S, 2), ``side_names`` (20,),
    ``control`` (T, 20, P, 2) and ``fit_error`` (T, 20) (the control points
    fitted in every frame and their largest distance from the true side, px),
    ``visible`` (T, 20, S) bool, ``draw_order`` (10,), ``alpha`` (T, H, W)
    uint8 coverage and ``size``.  Returns a summary dict (clip, character,
    motion, frames, max fit error).
    """
    folder = Path(folder)
    spec = character(character_name)
    clip = clip or f"{spec.name}-{motion_name}-{variation:02d}"
    kp = clip_points(spec, motion_name, n_frames, variation=variation, seed=seed, noise_px=0.0,
                     canvas=(size, size))
    sides, polys = body_geometry(kp, spec, size)
    rgb, alpha, labels = draw_frames(polys, spec, size)
    control, fit_err = fit_control_points(sides, control_points)
    folder.mkdir(parents=True, exist_ok=True)
    names = [frame_name(t) for t in range(n_frames)]
    for t, name in enumerate(names):
        ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb[t], cv2.COLOR_RGB2BGR))
        if not ok:
            raise OSError(f"could not encode {folder / name}")
        with atomic_path(folder / name) as tmp:
            tmp.write_bytes(buf.tobytes())
    write_npz(folder / "truth.npz", keypoints=kp, sides=sides,
              side_names=np.array(SIDE_NAMES, dtype="<U16"), control=control, fit_error=fit_err,
              visible=visibility(sides, labels), draw_order=np.array(DRAW_ORDER, dtype="<U16"),
              alpha=alpha, size=np.int64(size))
    ann = annotation_from_truth(clip, spec.name, motion_name, names, (size, size), control, kp,
                                keyframe_indices(n_frames, keyframe_every))
    write_annotation(ann, folder / "annotation.json")
    return {"clip": clip, "character": spec.name, "motion": motion_name, "frames": n_frames,
            "max_fit_error_px": float(fit_err.max())}


def annotation_from_truth(clip: str, character_name: str, motion_name: str, frames: list[str],
                          image_size: tuple[int, int], control: np.ndarray, keypoints: np.ndarray,
                          keyframes: list[int], decimals: int = 4) -> Annotation:
    """An :class:`Annotation` with the given keyframes taken from ``control`` ``(T, 20, P, 2)``
    (all 20 side curves) and ``keypoints`` ``(T, 17, 2)``; numbers rounded to ``decimals``."""
    kfs = []
    for t in keyframes:
        curves = {n: np.round(control[t, i], decimals) for i, n in enumerate(SIDE_NAMES)}
        calib = {g: np.stack([curves[f"{g}.a"][0], curves[f"{g}.b"][0],
                              curves[f"{g}.a"][-1], curves[f"{g}.b"][-1]]) for g in GROUPS}
        kfs.append(Keyframe(frame=int(t), curves=curves, calibration=calib,
                            keypoints=np.round(keypoints[t], decimals)))
    return Annotation(clip=clip, character=character_name, motion=motion_name, frames=list(frames),
                      image_size=(int(image_size[0]), int(image_size[1])), keyframes=kfs)


# --------------------------------------------------------------------------- rest-pose character

#: Rest-pose changes for a drawn character: arms out, legs apart (degrees).
REST_POSE = {"sho_r": -30.0, "sho_l": 30.0, "elb_r": -8.0, "elb_l": 8.0,
             "hip_r": -8.0, "hip_l": 8.0, "knee_r": 0.0, "knee_l": 0.0}


def rest_keypoints(spec: CharacterSpec, size: int) -> np.ndarray:
    """Rest pose ``(17, 2)`` px of a character on a ``size`` canvas, pelvis centred in x."""
    ch = np.array([REST_POSE.get(c, REST[c]) for c in CHANNELS], dtype=np.float64)
    angles = np.array([c in ANGLE_CHANNELS for c in CHANNELS])
    ch[angles] = np.deg2rad(ch[angles])
    kp = forward_kinematics(spec.proportions, ch[None, :], (size, size))[0]
    kp[:, 0] += 0.5 * size - kp[JOINT_INDEX["pelvis"], 0]
    return kp


def render_character(character_name: str, size: int = 256):
    """A character drawn in its rest pose (arms away from the body).

    Returns ``(rgba (size, size, 4) uint8, mask (size, size) bool,
    keypoints (17, 2) float64 px)``; RGB channels in RGB order, alpha 255 on
    the character (mask = more than half covered) and 0 elsewhere.
    """
    spec = character(character_name)
    kp = rest_keypoints(spec, size)
    _, polys = body_geometry(kp[None], spec, size)
    rgb, alpha, _ = draw_frames(polys, spec, size)
    mask = alpha[0] >= 128
    rgba = np.dstack([rgb[0], np.where(mask, 255, 0).astype(np.uint8)])
    return rgba, mask, kp



__all__ = [
    "BACKGROUND", "CANVAS", "CONTROL_POINTS", "DRAW_ORDER", "FAR_SHADE", "SIDE_SAMPLES",
    "annotation_from_truth", "body_geometry", "draw_frames", "frame_name", "keyframe_indices",
    "render_character", "render_clip", "rest_keypoints", "visibility",
    "JOINTS",
]
