"""Rebuild the two folders of gathered drawings that reshape-eval reads beside ``../shared/data``.

The drawings are not in the repository (they are data, with their own licences). This script
makes them again, byte for byte, from local git snapshots of their public sources, so that the
evaluation can be reproduced on a new machine:

    python scripts/gather_drawings.py --mirrors /work/.mirror \
        --heldout /work/extra-drawings --tuning /work/extra-drawings-tuning

``--mirrors`` holds one bare snapshot per source as ``<owner>+<name>/repo`` (what the project's
fetch tool makes; ``git clone --bare`` into the same layout works as well). Every file is read by
its git blob id, so a snapshot at another commit works as long as it still holds the same bytes;
a blob that is missing stops the script with its source and path. The joints of each drawing are
in ``tests/data/drawings/<name>.yaml``.

Each folder gets ``<name>/texture.png`` (verbatim), a ``mask.png`` for the opaque pencil
drawings (derived with ``nnsf.reshape.character.mask_from_border``, as ``mask: auto`` does), the
source's licence files (verbatim), and a README with source, commit, blob id, licence and SHA-256.
"""
from __future__ import annotations

import argparse
import hashlib
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

NOTO = ("googlefonts/noto-emoji", "b3e3051a088047d19fd4d49b1c3ac42fb8c3aaf8")
FLUENT = ("Ryhon0/fluentui-emoji-pack", "d7f4b862cf51bbe4be2f571e7316f66139d066bd")
GOPHERS = ("egonelbre/gophers", "63b1f5a9f334f9e23735c6e09ac003479ffe5df5")

# Licence files copied verbatim beside each drawing: (source, path, blob, name in the folder).
LICENCES = {
    NOTO: [("svg/LICENSE", "230517d8bd0f98a1c1789526878ed746ab2c939a", "LICENSE")],
    FLUENT: [("LICENSE", "9e841e7a26e4eb057b24511e7b92d42b257a80e5", "LICENSE")],
    GOPHERS: [("LICENSE-CC0", "9bd7c7e01d5e2685e2174affa177333b4f76bdc8", "LICENSE-CC0")],
}
LICENCE_TEXT = {
    NOTO: "Apache-2.0. The repository README puts tools and most image resources under the Apache "
          "licence 2.0; `svg/LICENSE` (copied as `LICENSE`) says the same. The root LICENSE at this "
          "commit is the SIL OFL 1.1, for the fonts only.",
    FLUENT: "MIT (`LICENSE`, Copyright (c) Microsoft Corporation). The pack's history is "
            "microsoft/fluentui-emoji's; the pack only lays the assets out by name.",
    GOPHERS: "CC0 for the drawings (README: \"The images and art-work in this repository are under "
             "CC0\"; `LICENSE-CC0`). The Go gopher is Renee French's design (CC BY 3.0): credit "
             "her wherever its frames are shown.",
}

# (set, name, source, path, blob, what it is)
DRAWINGS = [
    ("tuning", "noto_person_running", NOTO, "png/512/emoji_u1f3c3.png",
     None, "U+1F3C3 PERSON RUNNING, side view, the near forearm across the torso"),
    ("tuning", "noto_woman_running", NOTO, "png/512/emoji_u1f3c3_200d_2640.png",
     None, "U+1F3C3 U+200D U+2640 WOMAN RUNNING, side view"),
    ("tuning", "noto_person_kneeling", NOTO, "png/512/emoji_u1f9ce.png",
     None, "U+1F9CE PERSON KNEELING, side view, a forearm over the thigh"),
    ("tuning", "noto_person_cartwheeling", NOTO, "png/512/emoji_u1f938.png",
     None, "U+1F938 PERSON CARTWHEELING, drawn upside down on one hand, legs split"),
    ("tuning", "noto_person_handball", NOTO, "png/512/emoji_u1f93e.png",
     None, "U+1F93E PERSON PLAYING HANDBALL, a three-quarter throw: the far hand up with the ball "
           "behind the head, the near arm along the chest's edge"),
    ("tuning", "noto_person_juggling", NOTO, "png/512/emoji_u1f939.png",
     None, "U+1F939 JUGGLING, cut off at the trousers (no legs), arms raised, two balls apart from the body"),
    ("tuning", "noto_superhero", NOTO, "png/512/emoji_u1f9b8.png",
     None, "U+1F9B8 SUPERHERO, flying: a raised fist a few pixels of page from the hair, a cape behind the legs"),
    ("tuning", "fluent_person_running", FLUENT, "assets/Person running/Default/3D/person_running_3d_default.png",
     "513208dfab89a1e4689529199a51befc2375479f", "Fluent Emoji 3D \"Person running\", a shaded side view"),
    ("tuning", "gopher_sketch_ballet", GOPHERS, "sketch/arts/ballet-v2.png",
     "0662575beb478883829f3bd417c2981bc955c447", "coloured-pencil gopher ballerina on paper (opaque)"),
    ("heldout", "noto_person_standing", NOTO, "png/512/emoji_u1f9cd.png",
     None, "U+1F9CD PERSON STANDING, front view"),
    ("heldout", "noto_man_dancing", NOTO, "png/512/emoji_u1f57a.png",
     None, "U+1F57A MAN DANCING"),
    ("heldout", "noto_woman_dancing", NOTO, "png/512/emoji_u1f483.png",
     None, "U+1F483 WOMAN DANCING"),
    ("heldout", "fluent_person_fencing", FLUENT, "assets/Person fencing/3D/person_fencing_3d.png",
     "8f88874be1f10e3d709aec79793c072fa4dc6a5f", "Fluent Emoji 3D \"Person fencing\", a lunge"),
    ("heldout", "gopher_sketch_standing", GOPHERS, "sketch/misc/standing-left.png",
     "200c2939a53a26c761e5a7027bf7f3334cb4f675", "coloured-pencil gopher standing, on paper (opaque)"),
]


def git_blob(repo: Path, commit: str, path: str, blob: str | None) -> tuple[bytes, str]:
    """The bytes of ``path`` (by ``blob`` when given, else at ``commit``) and its blob id."""
    spec = blob or f"{commit}:{path}"
    done = subprocess.run(["git", "--git-dir", str(repo), "cat-file", "blob", spec],
                          capture_output=True)
    if done.returncode:
        raise SystemExit(f"gather_drawings: {repo}: cannot read {path} ({spec}); fetch the source first")
    sha = subprocess.run(["git", "--git-dir", str(repo), "hash-object", "--stdin"],
                         input=done.stdout, capture_output=True, check=True).stdout.decode().strip()
    return done.stdout, sha


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mirrors", type=Path, required=True)
    ap.add_argument("--heldout", type=Path, required=True)
    ap.add_argument("--tuning", type=Path, required=True)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from nnsf.reshape.character import mask_from_border

    out = {"tuning": args.tuning, "heldout": args.heldout}
    rows = {"tuning": [], "heldout": []}
    for kind, name, src, path, blob, what in DRAWINGS:
        repo = args.mirrors / src[0].replace("/", "+") / "repo"
        data, sha = git_blob(repo, src[1], path, blob)
        folder = out[kind] / name
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "texture.png").write_bytes(data)
        files = ["`texture.png` (verbatim)"]
        rgba = cv2.imread(str(folder / "texture.png"), cv2.IMREAD_UNCHANGED)
        if rgba.shape[2] == 4 and rgba[..., 3].min() == 255:
            mask = mask_from_border(rgba)
            cv2.imwrite(str(folder / "mask.png"), np.where(mask, 255, 0).astype(np.uint8))
            files.append("`mask.png` (derived: `mask_from_border`, the paper is opaque)")
        for lpath, lblob, lname in LICENCES[src]:
            (folder / lname).write_bytes(git_blob(repo, src[1], lpath, lblob)[0])
        h, w = rgba.shape[:2]
        rows[kind].append(
            f"### {name}/\n- {what}, {w}×{h}.\n- Source: **{src[0]}** `{path}` at `{src[1]}`, "
            f"git blob `{sha}`; SHA-256 of texture.png `{hashlib.sha256(data).hexdigest()}`.\n"
            f"- Files: {', '.join(files)}, licence files (verbatim).\n- Licence: {LICENCE_TEXT[src]}\n")
    for kind, folder in out.items():
        head = ("# Gathered drawings: the " + ("tuning" if kind == "tuning" else "held-out")
                + " set of reshape-eval\n\nMade by `scripts/gather_drawings.py` in the nnsf "
                "repository; joints in its `tests/data/drawings/<name>.yaml`.\n\n")
        (folder / "README.md").write_text(head + "\n".join(rows[kind]))
    print(f"gather_drawings: {len(DRAWINGS)} drawings into {args.tuning} and {args.heldout}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
