"""Fixtures for the rendering tests: tiny scenes written into a temporary folder.

Everything renders at 40 x 25 (or smaller) so the suite stays fast on 2 shared cores.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

import pytest

from render_testing import CAMERA, SUN
from spikesim._drjit import has_llvm

if not has_llvm():  # pragma: no cover - depends on the machine
    pytest.skip("Dr.Jit's LLVM backend is unavailable (libLLVM >= 17 missing)", allow_module_level=True)


@pytest.fixture
def make_scene(tmp_path: Path) -> Callable[..., Path]:
    """Write scene.xml (+ lights.json, + motion.json) and return the XML path."""

    def make(shapes: str, lights: dict[str, Any] | None = None, motion: dict[str, Any] | None = None,
             integrator: str = "direct", fov: float = 30.0, width: int = 40, height: int = 25,
             origin: str = "0, 0, 5", target: str = "0, 0, 0", name: str = "scene") -> Path:
        folder = tmp_path / name
        folder.mkdir(parents=True, exist_ok=True)
        xml = (f'<scene version="3.0.0">\n  <integrator type="{integrator}"/>'
               + CAMERA.format(fov=fov, origin=origin, target=target, width=width, height=height)
               + shapes + "\n</scene>\n")
        (folder / "scene.xml").write_text(xml)
        lights = lights if lights is not None else {"normal": {"emitters": [SUN]}}
        (folder / "lights.json").write_text(json.dumps(lights))
        if motion is not None:
            (folder / "motion.json").write_text(json.dumps(motion))
        return folder / "scene.xml"

    return make
