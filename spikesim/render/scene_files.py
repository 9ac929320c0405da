"""The files a scene is made of: its XML, its motion and light files, and every file the XML
references (meshes, textures, spectra), found without loading Mitsuba.

Two users: the renderer makes the references absolute before Mitsuba loads the XML from a string
(which would otherwise resolve them against the working directory, not the XML's folder), and
dataset generation hashes them all (spikesim.generation.inputs), so that a scene's identity is the
content of its files and not only their names.
"""
from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from ..config_io import file_problem
from .errors import SceneError

_PARAMETER = re.compile(r"\$(\w+)")


@dataclass(frozen=True)
class SceneFiles:
    """The files that make a scene: XML, motion (optional) and lights (optional when the XML
    has emitters of its own)."""

    name: str
    xml: Path
    motion: Path | None
    lights: Path | None

    @classmethod
    def resolve(cls, scene: str | Path, motion: str | Path | None = None,
                lights: str | Path | None = None) -> "SceneFiles":
        """`scene` is a bundled scene's name (scenes.scene_path) or a path to an XML file; the
        motion and light files default to `motion.json` and `lights.json` beside it, and each is
        optional there (a static scene; a scene lit by its own emitters). Given explicitly, a
        file must exist."""
        p = Path(scene)
        if p.suffix.lower() != ".xml" and not p.exists():
            from scenes import SCENES, scene_path
            if str(scene).lower() not in SCENES:
                raise SceneError(p, f"neither a bundled scene ({', '.join(SCENES)}) nor an existing XML file")
            p = scene_path(str(scene))
        if p.is_dir():
            p = p / "scene.xml"
        if (problem := file_problem(p)) is not None:
            raise SceneError(p, f"scene XML file {problem}")
        m = Path(motion) if motion is not None else p.parent / "motion.json"
        lt = Path(lights) if lights is not None else p.parent / "lights.json"
        for path, given, what in ((m, motion, "motion file"), (lt, lights, "light file")):
            problem = file_problem(path)
            # optional beside the XML, but one planted there that is not a regular file is refused
            if problem is not None and (given is not None or path.exists() or path.is_symlink()):
                raise SceneError(path, f"{what} {problem}")
        name = p.parent.name if p.name == "scene.xml" else p.stem
        return cls(name=name, xml=p.resolve(), motion=m.resolve() if m.is_file() else None,
                   lights=lt.resolve() if lt.is_file() else None)

    def digests(self) -> dict[str, str]:
        """sha256 of each file, so a description pins exactly what was rendered."""
        from spikesim.dataset import sha256_file
        return {key: sha256_file(path) for key in ("xml", "motion", "lights")
                if (path := getattr(self, key)) is not None}


@dataclass(frozen=True)
class FileReference:
    """One file a scene XML names: the element and attribute holding it, the value as written,
    and the file it means (None: a `$parameter` the XML's <default>s do not give)."""

    element: ET.Element
    attribute: str
    given: str
    path: Path | None


def xml_defaults(root: ET.Element) -> dict[str, str]:
    """The scene's `<default name=... value=...>` parameters."""
    return {d.get("name", ""): d.get("value", "") for d in root if d.tag == "default"}


def substitute(text: str, defaults: dict[str, str]) -> str | None:
    """`text` with its `$name` parameters replaced from `defaults`; None when one is not given
    there (Mitsuba then needs it at load time, and reports it if it is missing)."""
    names = _PARAMETER.findall(text)
    if any(n not in defaults for n in names):
        return None
    return _PARAMETER.sub(lambda m: defaults[m.group(1)], text)


def file_references(xml_path: Path, root: ET.Element) -> list[FileReference]:
    """Every file the parsed XML references, in document order: `<string name="filename"
    value=...>` (meshes, bitmaps) and any element's `filename` attribute (`<spectrum
    filename=...>`), resolved relative to the XML's folder as Mitsuba resolves them."""
    defaults = xml_defaults(root)
    base = Path(xml_path).parent
    out = []
    for el in root.iter():
        if el.tag == "string" and el.get("name") == "filename":
            attr = "value"
        elif "filename" in el.attrib and el.tag != "include":
            attr = "filename"
        else:
            continue
        given = el.get(attr, "")
        value = substitute(given, defaults)
        path = None if value is None else (Path(value) if Path(value).is_absolute() else base / value)
        out.append(FileReference(el, attr, given, path))
    return out


def referenced_files(xml_path: str | Path) -> list[tuple[str, Path]]:
    """(value as written, file) for each distinct file the scene XML at `xml_path` references;
    a SceneError naming the XML when it cannot be parsed or a file is missing."""
    xml_path = Path(xml_path)
    try:
        root = ET.parse(xml_path).getroot()
    except ET.ParseError as exc:
        raise SceneError(xml_path, f"not well-formed XML: {exc}") from None
    out: dict[Path, str] = {}
    for ref in file_references(xml_path, root):
        if ref.path is None:
            continue
        check_reference(xml_path, ref)
        out.setdefault(ref.path.resolve(), ref.given)
    return [(given, path) for path, given in out.items()]


def check_reference(xml_path: Path, ref: FileReference) -> None:
    """A SceneError naming the XML and the value when the referenced file does not exist or is not
    a regular file (a FIFO or /dev/zero as a mesh would block or never end)."""
    if ref.path is None or (problem := file_problem(ref.path)) is None:
        return
    if problem.startswith("does not exist"):
        raise SceneError(xml_path, f"references file {ref.given!r} (a texture, mesh or spectrum), which does "
                                   f"not exist (looked for {ref.path})")
    raise SceneError(xml_path, f"references file {ref.given!r} (a texture, mesh or spectrum), which {problem} "
                               f"({ref.path})")


__all__ = ["SceneFiles", "FileReference", "file_references", "referenced_files", "check_reference", "xml_defaults",
           "substitute"]
