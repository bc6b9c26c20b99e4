"""Template unification (docs/method.md §4, the paper's Eq. 4) and its inverse.

A character's points P (pixels, ``(n, 17, 2)``) map to features
X = W_char P + o, with W_char = D⁻¹ R D acting on the 17 points of a frame:

* D takes the root and the 16 bone vectors (child minus parent);
* R scales every bone b by r_b = L_b(template) / median_t L_b(character), and
  the root by s, the ratio of the template's to the character's leg-plus-torso
  length, so a jump's height is unified along with the body;
* o is a 2-vector per character added to every point: o = c − s·m, with m the
  character's median root position, so root *motion* is scaled about m (a
  scaled absolute position would encode the body's size, where the character
  stands on the canvas times s); c is shared by all characters and chosen when
  the unifier is fitted so that every unified coordinate is at least
  ``margin`` above zero.

The inverse P = W_char⁻¹ (X − o) maps features, including synthesized ones,
back onto a character's own proportions.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nnsf.errors import InputError
from nnsf.schema import List, Map, Num, Optional, Record, Str, check
from nnsf.skeleton.layout import BONE_NAMES, BONES, N_JOINTS, PARENTS, bone_lengths, to_features, to_points
from nnsf.skeleton.template import TEMPLATE_BONE_LENGTHS

# Bones whose lengths define the body scale s used for the root trajectory:
# the spine chain and both legs (indices into BONES).
_SCALE_BONES = [b for b, (p, c) in enumerate(BONES) if c in (1, 2, 3, 4, 5, 6, 7, 8)]
#: A bone no longer than this share of the legs' length has no measurable length in its view
#: (pixel precision, not a proportion: a drawn or captured bone is far longer).
END_ON = 1e-3


def difference_operator() -> np.ndarray:
    """D, ``(17, 17)``: row 0 picks the root, row j gives p_j − p_parent(j)."""
    D = np.eye(N_JOINTS)
    for j in range(1, N_JOINTS):
        D[j, PARENTS[j]] = -1.0
    return D


@dataclass
class CharacterScale:
    """Per-character unification factors.

    ``bone_ratio`` is r_b, shape ``(16,)``; ``root_scale`` is s;
    ``root_ref`` is m, the median root position ``(2,)`` in pixels.
    """

    bone_ratio: np.ndarray
    root_scale: float
    root_ref: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def matrix(self) -> np.ndarray:
        """W_char = D⁻¹ R D, ``(17, 17)``."""
        D = difference_operator()
        R = np.diag(np.concatenate([[self.root_scale], self.bone_ratio]))
        return np.linalg.solve(D, R @ D)

    def inverse_matrix(self) -> np.ndarray:
        """W_char⁻¹ = D⁻¹ R⁻¹ D, ``(17, 17)``."""
        D = difference_operator()
        Rinv = np.diag(1.0 / np.concatenate([[self.root_scale], self.bone_ratio]))
        return np.linalg.solve(D, Rinv @ D)


def character_scale(points: np.ndarray) -> CharacterScale:
    """Fit r_b and s from one character's frames ``(n, 17, 2)`` (pixels).

    A bone seen end-on (a projected 3D skeleton's hips in a side view: no
    measurable length, below :data:`END_ON` of the legs' length) tells nothing
    of the character's proportions, so it gets the body's overall scale ``s``
    instead of being stretched to the template's length.  Raises
    ``ValueError`` when the body itself has no extent.
    """
    lengths = np.median(bone_lengths(points), axis=0)
    legs = lengths[_SCALE_BONES].sum()
    if not (np.isfinite(lengths).all() and legs > 0):
        bad = np.flatnonzero(~(lengths > 0))
        raise ValueError(f"bone {BONE_NAMES[bad[0] if bad.size else _SCALE_BONES[0]]} has zero median length")
    scale = TEMPLATE_BONE_LENGTHS[_SCALE_BONES].sum() / legs
    end_on = lengths <= END_ON * legs
    ratio = np.where(end_on, scale, TEMPLATE_BONE_LENGTHS / np.where(end_on, 1.0, lengths))
    return CharacterScale(bone_ratio=ratio, root_scale=float(scale),
                          root_ref=np.median(points[:, 0, :], axis=0))


def _vector(n: int, lo: float = -1e12, hi: float = 1e12) -> List:
    return List(Num(lo, hi), min_len=n, max_len=n)


#: A unifier as :meth:`Unifier.to_dict` writes it (``unifier.json``, a model file's ``meta.unifier``).
UNIFIER = Record({
    "margin": Num(0.0, 1e6),
    "offset": _vector(2),
    "bones": Optional(List(Str(choices=tuple(BONE_NAMES)), min_len=len(BONE_NAMES), max_len=len(BONE_NAMES))),
    "characters": Map(Record({"bone_ratio": _vector(len(BONE_NAMES), 1e-12), "root_scale": Num(1e-12, 1e12),
                              "root_ref": _vector(2)}), max_len=100_000),
})


@dataclass
class Unifier:
    """Maps each character's pixel points to non-negative template features.

    Fit with :meth:`fit` on all characters' frames; then :meth:`transform`
    gives features ``(n, 34)`` (template units, every value ≥ ``margin``) and
    :meth:`inverse_transform` maps features back to a named character's pixels.
    """

    margin: float = 0.5
    scales: dict[str, CharacterScale] = field(default_factory=dict)
    offset: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def fit(self, points: np.ndarray, characters: np.ndarray) -> "Unifier":
        """Fit per-character factors and the shared offset o.

        points : ``(n, 17, 2)`` pixels; characters : ``(n,)`` names.
        """
        points = np.asarray(points, dtype=float)
        characters = np.asarray(characters).astype(str)
        self.scales = {c: character_scale(points[characters == c]) for c in np.unique(characters)}
        self.offset = np.zeros(2)
        raw = self._linear(points, characters)
        self.offset = self.margin - raw.reshape(-1, 2).min(axis=0)
        return self

    def _linear(self, points: np.ndarray, characters: np.ndarray) -> np.ndarray:
        out = np.empty_like(points, dtype=float)
        for c in np.unique(characters):
            if c not in self.scales:
                raise KeyError(c)
            rows = characters == c
            sc = self.scales[c]
            out[rows] = np.einsum("ij,njc->nic", sc.matrix(), points[rows]) - sc.root_scale * sc.root_ref
        return out

    def transform(self, points: np.ndarray, characters) -> np.ndarray:
        """Pixel points ``(n, 17, 2)`` -> unified features ``(n, 34)``.

        Raises ``ValueError`` if a point would fall below zero (input far
        outside what the unifier was fitted on) or a character is unknown.
        """
        points = np.asarray(points, dtype=float)
        characters = np.broadcast_to(np.asarray(characters).astype(str), points.shape[:1])
        unknown = sorted(set(np.unique(characters)) - set(self.scales))
        if unknown:
            raise ValueError(f"unknown character(s) {unknown}; fitted on {sorted(self.scales)}")
        # Eq. 4 (docs/method.md §4): X = W_char P + o.
        X = to_features(self._linear(points, characters) + self.offset)
        if X.size and X.min() < 0:
            raise ValueError(
                f"unified features reach {X.min():.3g} < 0: the input lies outside the range the "
                "unifier was fitted on; refit it including these frames or raise the margin"
            )
        return X

    def inverse_transform(self, features: np.ndarray, character: str) -> np.ndarray:
        """Unified features ``(n, 34)`` -> pixel points ``(n, 17, 2)`` of ``character``."""
        if character not in self.scales:
            raise ValueError(f"unknown character {character!r}; fitted on {sorted(self.scales)}")
        sc = self.scales[character]
        P = to_points(features) - self.offset + sc.root_scale * sc.root_ref
        return np.einsum("ij,njc->nic", sc.inverse_matrix(), P)

    def to_dict(self) -> dict:
        """JSON-ready description (round-trips through :meth:`from_dict`)."""
        return {
            "margin": self.margin,
            "offset": self.offset.tolist(),
            "bones": list(BONE_NAMES),
            "characters": {
                c: {"bone_ratio": s.bone_ratio.tolist(), "root_scale": s.root_scale,
                    "root_ref": s.root_ref.tolist()}
                for c, s in sorted(self.scales.items())
            },
        }

    @classmethod
    def from_dict(cls, d: dict, source="unifier") -> "Unifier":
        """The unifier :meth:`to_dict` described; an :class:`~nnsf.errors.InputError` naming ``source``
        and the field when ``d`` does not follow :data:`UNIFIER`."""
        d = check(source, UNIFIER, d)
        if "bones" in d and d["bones"] != list(BONE_NAMES):
            raise InputError(source, "bones", "the bones of this nnsf's skeleton, in its order", d["bones"])
        return cls(
            margin=float(d["margin"]),
            offset=np.asarray(d["offset"], dtype=float),
            scales={
                c: CharacterScale(np.asarray(v["bone_ratio"], dtype=float), float(v["root_scale"]),
                                  np.asarray(v["root_ref"], dtype=float))
                for c, v in d["characters"].items()
            },
        )
