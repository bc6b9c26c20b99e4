"""Which skeleton family a BVH file belongs to, from its joint names alone.

:func:`rank_families` scores every family of
:data:`~nnsf.datasets.bvh_skeletons.FAMILIES`.  A name counts as evidence in
proportion to how specific it is: a name that ``d`` families write weighs
``1/d`` (``Head`` is weak evidence, ``LeftInHandIndex`` strong).  Recall is
the weighted share of the family's signature names the file has; precision
the weighted share of the file's recognised names that the family writes (a
name no family writes is neutral).  The score is their harmonic mean, in
[0, 1].  A family is chosen (:func:`detect_family`) only when it maps all 17
key points, scores at least :data:`WEAK_SCORE` and leads every other family
by at least :data:`SCORE_MARGIN`; otherwise the error lists the candidates,
so that a user can pick one or write a joint map
(:mod:`nnsf.datasets.joint_map`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

from nnsf.datasets.bvh_skeletons import FAMILIES, JointNames, SkeletonFamily, first_rule
from nnsf.errors import InputError
from nnsf.skeleton.layout import JOINTS

__all__ = ["FamilyMatch", "WEAK_SCORE", "SCORE_MARGIN", "rank_families", "detect_family", "choose_family"]

#: Below this score a family is a weak match: the names say little about it.
WEAK_SCORE = 0.5
#: The chosen family must lead the next one by this much (about one name in ten).
SCORE_MARGIN = 0.1


@dataclass
class FamilyMatch:
    """How well a family fits a file's joint names (:func:`rank_families`).

    score : harmonic mean of ``precision`` and ``recall`` (weighted names), in [0, 1].
    mapped : key points the family's rules can make from the file's nodes (of 17).
    missing : node name -> key points that need it, for the key points not mapped.
    """

    family: SkeletonFamily
    score: float
    precision: float
    recall: float
    mapped: int
    missing: dict[str, list[str]]

    def summary(self, detail: bool = False, shown: int = 6) -> str:
        """One line: name, score, key points mapped, and (at most ``shown``) joints it lacks;
        with ``detail`` also the key points those joints would make."""
        text = f"{self.family.name} (score {self.score:.2f}, maps {self.mapped} of 17 key points"
        if self.missing:
            names = sorted(self.missing)
            text += "; lacks " + ", ".join(names[:shown]) + (", ..." if len(names) > shown else "")
            if detail:
                kps = sorted({k for v in self.missing.values() for k in v}, key=JOINTS.index)
                text += " for " + ", ".join(kps)
        return text + ")"


def _name_weights(families: Iterable[SkeletonFamily], forms: list[tuple[str, ...]]) -> dict[str, float]:
    """Weight 1/d of every name form, d = how many families write it (0 if none)."""
    fams = list(families)
    out: dict[str, float] = {}
    every = {f for forms_ in forms for f in forms_} | {n for fam in fams for n in fam.signature}
    for form in every:
        d = sum(fam.writes(form) for fam in fams)
        out[form] = 1.0 / d if d else 0.0
    return out


def rank_families(names: Sequence[str], end_sites: Sequence[bool] | None = None,
                  families: Mapping[str, SkeletonFamily] | None = None) -> list[FamilyMatch]:
    """Every family scored on the joint names (module docstring), best first.

    ``names`` are the file's node names in order, ``end_sites`` marks the End
    Sites among them (not scored, but rules may use them; see
    :class:`~nnsf.datasets.bvh_skeletons.JointNames`).
    """
    families = FAMILIES if families is None else families
    nm = JointNames(names, end_sites)
    joint_forms = [nm.forms[i] for i in nm.joints]
    weight = _name_weights(families.values(), joint_forms)

    def form_weight(forms):  # a node counts once, by its best-known form
        return max(weight.get(f, 0.0) for f in forms)

    present = {f for forms in joint_forms for f in forms}
    out = []
    for fam in families.values():
        sig = fam.signature
        total = sum(weight[n] for n in sig)
        recall = sum(weight[n] for n in sig if n in present) / total if total else 0.0
        seen = [forms for forms in joint_forms if form_weight(forms) > 0]
        known = sum(form_weight(forms) for forms in seen if any(fam.writes(f) for f in forms))
        all_w = sum(form_weight(forms) for forms in seen)
        precision = known / all_w if all_w else 0.0
        score = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
        missing: dict[str, list[str]] = {}
        mapped = 0
        for kp in JOINTS:
            if first_rule(fam, kp, nm) is not None:
                mapped += 1
            else:
                for n in fam.rules[kp][0].names():
                    if not nm.has(n):
                        missing.setdefault(n, []).append(kp)
        out.append(FamilyMatch(fam, score, precision, recall, mapped, missing))
    out.sort(key=lambda m: (-m.score, -m.mapped, m.family.name))
    return out


def detect_family(names, source="<bvh>", end_sites=None) -> SkeletonFamily:
    """The built-in family the joint ``names`` clearly belong to.

    Chosen only when it maps all 17 key points, scores at least
    :data:`WEAK_SCORE` and no other family comes within :data:`SCORE_MARGIN`
    of it.  Otherwise raises :class:`InputError` naming ``source``, the
    field ``joint names`` and the candidates (score, key points mapped, the
    joints they lack), and pointing at ``--joint-map``.
    """
    return choose_family(rank_families(names, end_sites), source)


def choose_family(ranked: list[FamilyMatch], source="<bvh>") -> SkeletonFamily:
    """The decision of :func:`detect_family` on a ranking from :func:`rank_families`."""
    full = [m for m in ranked if m.mapped == len(JOINTS)]
    best = full[0] if full else None
    if best is not None and best.score >= WEAK_SCORE:
        rivals = [m for m in ranked if m is not best and m.score > best.score - SCORE_MARGIN]
        if not rivals:
            return best.family
        why = "joint names that tell one family apart; these fit about equally"
        shown = [best] + rivals
    elif best is not None:
        why = f"joint names of a known family; the best match is weak (score below {WEAK_SCORE:g})"
        shown = [best] + [m for m in ranked if m is not best][:2]
    elif ranked and ranked[0].score > 0:
        why = "joint names of a known family; none maps all 17 key points"
        shown = ranked[:3]
    else:
        raise InputError(source, "joint names", "joint names of a known family (give --joint-map "
                         "FILE.yaml, docs/formats.md §3.3)",
                         reason=f"candidates: none of {', '.join(FAMILIES)} writes any of them")
    raise InputError(source, "joint names",
                     why + " (give --joint-map FILE.yaml, docs/formats.md §3.3)",
                     reason="candidates: " + "; ".join(m.summary(detail=k == 0) for k, m in enumerate(shown[:4])))
