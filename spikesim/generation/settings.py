"""The settings a generation uses, and where each came from; and the same for every command that
renders a scene (`render`, `simulate --scene`): one place decides what a scene's own file sets.

Layers, later ones winning: the preset (a command's defaults); for a user's own scene, its XML's
film size and sampler samples per pixel (a user scene keeps its own film and spp); a camera
file's height and width; a render-settings file; each command-line flag; and a quality preset,
which sets the render knobs it was measured with (`scene_layers` holds the middle ones). The
result is a Preset for planning and, for each setting, its value and origin, which `generate`
prints and records in each scene's meta.json (`render` in render.json, `simulate` in the sidecar).
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from spikesim.generation.plan import PRESET_RENDER_KNOBS, PRESETS, Preset
from spikesim.render.scene_files import substitute, xml_defaults
from spikesim.render_settings import RenderSettings, merge_layers

#: The settings each kind of dataset uses (the others would be ignored, so they are not reported).
KIND_SETTINGS = {
    "llr": ("camera", "height", "width", "llr_windows", *PRESET_RENDER_KNOBS),
    "rllr": ("camera", "height", "width", "rllr_scenes", "rllr_steps", "rllr_gt_stride", *PRESET_RENDER_KNOBS),
    "scene": ("camera", "height", "width", "llr_windows", *PRESET_RENDER_KNOBS),
    # a user scene given a length (--steps, --gt-stride) as RLLR scenes are, not windows
    "scene-steps": ("camera", "height", "width", "rllr_steps", "rllr_gt_stride", *PRESET_RENDER_KNOBS),
    # `render` and `simulate --scene`
    "command": ("camera", "height", "width", "spp", "gt_spp", "light_power_factor"),
}
#: The fields of a camera file that set the film, which a run takes as a layer of its settings.
CAMERA_GEOMETRY = ("height", "width")
#: What a render-settings file may set for a dataset (seed, device and resolution are per job).
FILE_SETTINGS = (*PRESET_RENDER_KNOBS, "resolution")


@dataclass(frozen=True)
class ResolvedSettings:
    """A preset with every layer applied, and the origin of each value that applies."""

    preset: Preset | None
    """What the jobs are planned from, a quality's knobs included (None for a command, which
    plans no jobs)."""
    values: dict[str, Any]
    """Every setting as the jobs use it, a quality's knobs included."""
    origins: dict[str, str]
    kind: str

    def table(self) -> dict[str, dict[str, Any]]:
        """{setting: {"value": v, "from": origin}} for the settings this kind uses."""
        return {k: {"value": self.values[k], "from": self.origins[k]} for k in KIND_SETTINGS[self.kind]
                if k in self.values}

    def summary(self) -> str:
        """One line: each setting with its origin, named as its flag is (`steps`, not the preset's
        field `rllr_steps`; the recorded table keeps the field names)."""
        return "settings: " + ", ".join(f"{SHOWN_AS.get(k, k)} {v['value']} ({v['from']})"
                                        for k, v in self.table().items())


#: The name a setting is shown by: the flag that sets it (generate --steps, --gt-stride, --windows,
#: --count), where the preset's field has another name.
SHOWN_AS = {"rllr_steps": "steps", "rllr_gt_stride": "gt_stride", "llr_windows": "windows", "rllr_scenes": "count"}


#: The most samples per pixel a scene file may ask for (the reference preset uses 64): more is a
#: typo, and Mitsuba cannot render it in one pass (spikesim.render_settings.check_samples).
MAX_SPP = 1 << 20


def _xml_int(xml: str | Path, el: ET.Element, name: str, what: str, defaults: Mapping[str, str],
             limit: int | None = None) -> int | None:
    """An <integer name=...> child's value (None: not given, or a $parameter the XML's <default>s
    do not give), with $parameters read from the <default>s; a ValueError naming the XML and the
    value when it is not a positive integer (up to `limit`)."""
    for child in el:
        if child.tag == "integer" and child.get("name") == name:
            given = child.get("value", "")
            text = substitute(given, defaults)
            if text is None:
                return None
            try:
                value = int(text.strip())
            except ValueError:
                raise ValueError(f"{xml}: {what} {given!r} is not an integer") from None
            if value < 1:
                raise ValueError(f"{xml}: {what} {value} must be a positive integer")
            if limit is not None and value > limit:
                raise ValueError(f"{xml}: {what} {value} is more than {limit}")
            return value
    return None


def scene_file_settings(xml: str | Path) -> dict[str, int]:
    """The film size (height, width) and the sampler's sample_count (spp) a Mitsuba scene file
    declares for its sensor; settings it does not declare are left out. A declared value that is
    not a positive integer (0, -5, "4e9") or an spp above MAX_SPP is refused with one line naming
    the XML and the value, rather than replaced by the preset's without a word."""
    try:
        root = ET.parse(xml).getroot()
    except (ET.ParseError, OSError) as exc:
        raise ValueError(f"{xml}: cannot read the scene's film and sampler ({exc})") from None
    defaults = xml_defaults(root)
    out: dict[str, int] = {}
    for sensor in (el for el in root if el.tag == "sensor"):
        for child in sensor:
            if child.tag == "film":
                for key in ("height", "width"):
                    if (v := _xml_int(xml, child, key, f"film {key}", defaults)) is not None:
                        out[key] = v
            if child.tag == "sampler":
                if (v := _xml_int(xml, child, "sample_count", "sampler sample_count", defaults, MAX_SPP)) is not None:
                    out["spp"] = v
        break  # the first sensor, as the renderer
    return out


def settings_file_values(path: str | Path) -> dict[str, Any]:
    """The settings a render-settings file (JSON or TOML, RenderSettings fields) gives a dataset;
    errors name the file."""
    from spikesim.config_io import read_config_file

    data = read_config_file(path)
    unknown = sorted(set(data) - set(FILE_SETTINGS))
    if unknown:
        raise ValueError(f"render settings {path}: {unknown} cannot be set for a dataset; it may set "
                         f"{list(FILE_SETTINGS)}")
    try:
        RenderSettings.from_dict(data)  # the checks every render setting gets
    except (TypeError, ValueError) as exc:
        raise ValueError(f"render settings {path}: {exc}") from None
    out = {k: v for k, v in data.items() if k != "resolution"}
    if data.get("resolution") is not None:
        out["height"], out["width"] = data["resolution"]
    return out


def camera_name(camera: str | Path | None) -> str:
    """How a --camera value is shown: a built-in camera's name, or the file's path."""
    return "realistic" if camera is None else str(camera)


def camera_file_geometry(camera: str | Path | None) -> dict[str, int]:
    """The film fields (CAMERA_GEOMETRY) a camera file sets; {} for a built-in camera."""
    if not isinstance(camera, Path):
        return {}
    from spikesim.config_io import read_config_file
    data = read_config_file(camera)
    return {k: data[k] for k in CAMERA_GEOMETRY if data.get(k) is not None}


def scene_layers(xml: str | Path | None, camera: str | Path | None = None) -> list[tuple[str, Mapping[str, Any]]]:
    """The layers a scene's own file and a --camera value add above a command's defaults, in
    their order: the camera (named, so the settings say which), the scene's film and spp, then a
    camera file's height and width (a camera file that sets them is used, never ignored)."""
    layers: list[tuple[str, Mapping[str, Any]]] = [
        ("default" if camera is None else "--camera", {"camera": camera_name(camera)})]
    if xml is not None:
        layers.append((f"scene file {Path(xml).name}", scene_file_settings(xml)))
    if geometry := camera_file_geometry(camera):
        layers.append((f"--camera {Path(camera).name}", geometry))
    return layers


#: The ground truth's samples for a user's scene when no preset is asked for. The small preset's 16
#: (sized for the tests and the demo) leave visible Monte Carlo grain: a 16-spp ground truth is
#: 24-38 dB from a 128-spp one on the LLR scenes, a 64-spp one 29-43 dB (docs/tradeoff.md section
#: 6), above what the networks score, so the truth's own error stays below theirs.
USER_SCENE_GT_SPP = 64
USER_SCENE_GT_ORIGIN = "a user scene without --preset (docs/tradeoff.md: 16 spp is grainy)"


def resolve_settings(kind: str, preset: str | Preset = "small", xml: str | Path | None = None,
                     settings_file: str | Path | None = None, flags: Mapping[str, Any] | None = None,
                     quality: str | None = None, camera: str | Path | None = None,
                     preset_given: bool = True) -> ResolvedSettings:
    """Merge the layers (see the module's docstring). `flags` maps a flag as the user wrote it
    ("--spp") to {setting: value} (None: not given). A quality's render knobs are reported as
    coming from it, and planned with: the jobs record the values their renderer is given. A
    user scene given --steps or --gt-stride is planned as RLLR scenes are (kind "scene-steps")."""
    if kind not in KIND_SETTINGS or kind == "command":
        raise ValueError(f"kind={kind!r}; expected one of {sorted(set(KIND_SETTINGS) - {'command'})}")
    base = PRESETS[preset] if isinstance(preset, str) else preset
    layers: list[tuple[str, Mapping[str, Any] | None]] = [(f"preset {base.name}", base.values())]
    if kind.startswith("scene") and not preset_given and base.render.gt_spp < USER_SCENE_GT_SPP:
        layers.append((USER_SCENE_GT_ORIGIN, {"gt_spp": USER_SCENE_GT_SPP}))
    layers += scene_layers(xml if kind.startswith("scene") else None, camera)
    if settings_file is not None:
        layers.append((f"--render-settings {settings_file}", settings_file_values(settings_file)))
    layers += list((flags or {}).items())
    q = None
    if quality is not None:
        from spikesim.quality import QualitySettings
        q = QualitySettings.from_name(quality)  # resolved once here; each job holds its own (SceneJob)
        layers.append((f"--quality {quality}", q.render_kwargs()))
    values, origins = merge_layers(layers)
    if q is not None and (rule := q.sample_rule) is not None:
        if origins.get("spp") == f"--quality {quality}":  # run_job picks it per scene from probe renders
            origins["spp"] = (f"--quality {quality}: per scene, 1-{rule.max_spp} by its Monte Carlo noise "
                              f"(predicted loss <= {rule.tolerance_db:g} dB)")
    if q is not None and q.keyframe_policy == "adaptive":
        if origins.get("keyframe_every") == f"--quality {quality}":  # the renderer places keyframes by motion
            origins["keyframe_every"] = (f"--quality {quality}: adaptive, not this fixed spacing: a keyframe where "
                                         f"the image has moved {q.max_px_per_keyframe:g} px, at most "
                                         f"{q.max_interval} steps apart")
    if kind == "scene" and any(origins.get(k, "").startswith("--") for k in ("rllr_steps", "rllr_gt_stride")):
        kind = "scene-steps"
    planned = {k: v for k, v in values.items() if k != "camera"}
    return ResolvedSettings(base.replace(**planned), values, origins, kind)


def resolve_command_settings(xml: str | Path, defaults: Mapping[str, Any], camera: str | Path | None = None,
                             settings: Mapping[str, Any] | None = None, settings_origin: str = "--render-settings",
                             flags: Mapping[str, Any] | None = None) -> ResolvedSettings:
    """The film, samples and light power factor of a command that renders a scene (`render`,
    `simulate --scene`): its `defaults` (origin "default"), then the layers `generate` gives a
    scene (`scene_layers`: the XML's film and spp, a camera file's size), then a render-settings
    file's `settings` (its resolution as height and width), then the `flags`."""
    file_values = dict(settings or {})
    if file_values.get("resolution") is not None:
        file_values["height"], file_values["width"] = file_values.pop("resolution")
    file_values = {k: v for k, v in file_values.items() if k in KIND_SETTINGS["command"]}
    layers: list[tuple[str, Mapping[str, Any] | None]] = [("default", defaults), *scene_layers(xml, camera),
                                                          (settings_origin, file_values), *(flags or {}).items()]
    values, origins = merge_layers(layers)
    return ResolvedSettings(None, values, origins, "command")


__all__ = ["USER_SCENE_GT_SPP", "ResolvedSettings", "resolve_settings", "resolve_command_settings", "scene_file_settings",
           "scene_layers", "settings_file_values", "KIND_SETTINGS"]
