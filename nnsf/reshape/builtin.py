"""Built-in characters: the synthetic dataset's figures drawn at rest (:mod:`nnsf.frames.render`)."""
from __future__ import annotations

from pathlib import Path

from nnsf.datasets.synthetic import character as synthetic_character_spec
from nnsf.errors import InputError
from nnsf.frames.render import render_character
from nnsf.reshape.character import Character, write_character


def synthetic_character(name: str, size: int = 512, source="params.yaml") -> Character:
    """A built-in synthetic character drawn at rest (``nnsf.frames.render``); the stick figure if absent."""
    try:
        rgba, mask, kp = render_character(name, size)
    except ValueError as exc:
        raise InputError(source, "reshape.character", "a built-in character name or a character "
                         "file/folder", reason=str(exc)) from None
    return Character(name=name, texture=rgba, mask=mask, keypoints=kp, source=f"<rendered {name}>")


def write_rendered_character(name: str, folder, size: int = 256) -> Path:
    """Write ``<folder>/<name>.json`` (+ texture and mask PNGs) in the
    :func:`nnsf.reshape.character.write_character` format; returns the JSON path."""
    rgba, mask, kp = render_character(name, size)
    ch = Character(name=synthetic_character_spec(name).name, texture=rgba, mask=mask, keypoints=kp,
                   source=f"<rendered {name}>")
    return write_character(ch, Path(folder) / f"{ch.name}.json")
