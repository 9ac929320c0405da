"""The bundled test scenes of the LLR dataset (paper, section "Reconstruction Datasets").

Each scene is a folder: `scene.xml` (Mitsuba 3 geometry, materials, camera), `motion.json`
(what moves and how), `lights.json` (the "normal" and "low" lighting, physical units), and the
textures and meshes `build_assets.py` generates. docs/scenes.md describes them.
"""
from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parent
#: The paper's five LLR scenes.
SCENES = ("ball", "car", "cook", "fan", "rotate")


def scene_path(name: str) -> Path:
    """Path of a bundled scene's XML file; `name` is case-insensitive ("Ball" or "ball")."""
    key = str(name).lower()
    if key not in SCENES:
        raise KeyError(f"unknown scene {name!r}; bundled scenes are {list(SCENES)}")
    return ROOT / key / "scene.xml"


__all__ = ["ROOT", "SCENES", "scene_path"]
