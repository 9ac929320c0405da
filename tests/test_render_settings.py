"""One record of render settings (spikesim.render_settings.RenderSettings), held by the
renderer, the quality presets, the generation presets and the trade study, and one merge of
layers of settings that says where each value came from."""
from __future__ import annotations

import dataclasses

import pytest

from spikesim.render_settings import RENDER_KNOBS, RenderSettings, merge_layers


def test_the_render_knobs_are_declared_once():
    from spikesim.generation import Preset
    from spikesim.quality import QualitySettings
    from pipelines.tradeoff_study import StudyConfig

    for cls in (Preset, QualitySettings, StudyConfig):
        names = {f.name for f in dataclasses.fields(cls)}
        assert not names & {"spp", "gt_spp", "variant", "keyframe_every", "ref_spp"}, cls
        assert any(f.type in ("RenderSettings", RenderSettings) for f in dataclasses.fields(cls)), cls


def test_the_records_read_their_knobs_from_one_render_settings():
    from spikesim.generation import PRESETS
    from spikesim.quality import PRESETS as QUALITIES
    from pipelines.tradeoff_study import StudyConfig

    small = PRESETS["small"].replace(spp=3, keyframe_every=5, height=9)
    assert (small.spp, small.render.spp, small.keyframe_every, small.height) == (3, 3, 5, 9)
    draft = QUALITIES["draft"].replace(spp=2)
    assert draft.render.spp == 2 and draft.to_dict()["spp"] == 2 and draft.name == "draft"
    cfg = StudyConfig.of(ref_spp=8, gt_spp=16, resolution=(20, 30), seed=4)
    assert cfg.reference == RenderSettings(variant="spectral", spp=8, gt_spp=16, resolution=(20, 30), seed=4)
    assert (cfg.ref_spp, cfg.gt_spp, cfg.resolution, cfg.seed) == (8, 16, (20, 30), 4)


def test_render_settings_check_their_knobs_once_for_everyone():
    from spikesim.generation import PRESETS
    from spikesim.quality import QualitySettings

    with pytest.raises(ValueError, match="keyframe_every"):
        PRESETS["small"].replace(keyframe_every=0)
    with pytest.raises(ValueError, match="spp"):
        QualitySettings.of("q", keyframe_policy="every", spp=0)
    with pytest.raises(ValueError, match="render settings"):
        RenderSettings.from_dict({"spp": 2, "sample_count": 4})


def test_merged_layers_say_where_each_value_came_from():
    values, origins = merge_layers([("default", RenderSettings().to_dict()), ("preset small", {"spp": 2, "gt_spp": 16}),
                                    ("scene XML", {"spp": 16, "resolution": (50, 80)}),
                                    ("--gt-spp", {"gt_spp": 8}), ("--spp", {"spp": None})])
    assert values["spp"] == 16 and origins["spp"] == "scene XML"  # None: not given
    assert values["gt_spp"] == 8 and origins["gt_spp"] == "--gt-spp"
    assert origins["variant"] == "default" and set(values) == set(RENDER_KNOBS)
    assert RenderSettings.from_dict(values).resolution == (50, 80)
