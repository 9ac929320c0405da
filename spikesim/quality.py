"""One `quality` option (fast / draft / balanced / reference) for the render + sensor knobs, the
rule that switches off noise terms a scene's light level cannot show, and the sample rule that
renders each scene with the samples its Monte Carlo noise needs (`SampleRule`, derived by
spikesim.preset_rule).

The presets were chosen from the measured speed/accuracy Pareto front of `spikesim tradeoff`
(docs/tradeoff.md); the numbers that justify each choice are in PRESETS below. Every run records
the settings it used (`QualitySettings.to_dict()`, plus the noise decisions) in its meta.json.
"""
from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import Any, Iterable, Iterator

import numpy as np

from .camera import NOISE_TERMS, PRECISIONS, SpikeCamera
from .keyframes import keyframe_steps
from .render_settings import HoldsRenderSettings, RenderSettings, split_render_knobs

log = logging.getLogger(__name__)

KEYFRAME_POLICIES = ("every", "fixed", "adaptive")
NOISE_POLICIES = ("all", "auto")
VARIANTS = ("auto", "mono", "spectral")


# ---- noise terms a light level cannot show ------------------------------------------------------
@dataclass(frozen=True)
class NoiseDecision:
    """Whether one noise term is simulated, and why (for the log and meta.json)."""

    term: str
    effect: float | None
    """Largest relative effect on a window's spike count over the given light levels (None: not
    evaluated, the quality keeps every term)."""
    keep: bool
    reason: str

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def noise_effect(camera: SpikeCamera, term: str, y: float, window: int = 41) -> float:
    """Relative effect of one noise term on the spike count of a `window`-step window at light y.

    With c = (y + d) W the expected count (d: dark thresholds per step; the long-run rate of an
    integrate-and-fire pixel is y + d, docs/design.md section 2), each term changes the count by:
    - dark_current_hz: d W of c (additive dark charge)            -> d / (y + d)
    - dark_current_spread: its pixel-to-pixel CV times that       -> cv d / (y + d)
    - gain_spread (PRNU): rate g y + d, g ~ 1 +- sigma_g          -> sigma_g y / (y + d)
    - row_gain_spread / column_gain_spread: the same, per row or column
    - outlier_pixel_fraction / _gain_spread: a fraction f of pixels with gain 1 +- sigma_o
                                                                  -> sqrt(f) sigma_o y / (y + d)
    - threshold_mismatch / _offset: rate scales as 1 / theta      -> sigma
    - comparator_noise: each comparison moves by sigma_c thresholds, so a window's count moves by
      about sigma_c spikes at each of its two edges               -> sqrt(2) sigma_c / c
    - shot_noise: Poisson charge in the window, (y + d) W N_e electrons (N_e per threshold)
                                                                  -> 1 / sqrt(c N_e)
    - reset_loss: a fraction r of the step after each spike, (y + d) of the steps -> r min(y + d, 1)
    - random_initial_state: shifts the first window's count by up to one spike -> 1 / c
    """
    if term not in NOISE_TERMS:
        raise ValueError(f"unknown noise term {term!r}; known: {sorted(NOISE_TERMS)}")
    if not (isinstance(y, (int, float, np.floating)) and math.isfinite(y) and y >= 0):
        raise ValueError(f"light level y={y!r} must be a finite number >= 0 (spikes per step)")
    if getattr(camera, term) == NOISE_TERMS[term]:
        return 0.0
    d = camera.dark_per_step
    rate = min(float(y) + d, 1.0)  # at most one spike per step (saturation)
    if rate <= 0:
        return 0.0  # no light, no dark current: nothing fires, nothing to perturb
    count = rate * window
    if term == "dark_current_hz":
        return d / (y + d)
    if term == "dark_current_spread":
        return camera.dark_current_spread * d / (y + d)
    if term in ("gain_spread", "row_gain_spread", "column_gain_spread"):
        return float(getattr(camera, term)) * y / (y + d)
    if term in ("outlier_pixel_fraction", "outlier_gain_spread"):  # rms over pixels: sqrt(f) sigma_o
        return math.sqrt(camera.outlier_pixel_fraction) * camera.outlier_gain_spread * y / (y + d)
    if term in ("threshold_mismatch", "threshold_offset"):
        return float(getattr(camera, term))
    if term == "comparator_noise":
        return math.sqrt(2.0) * camera.comparator_noise / count
    if term == "shot_noise":
        return 1.0 / math.sqrt(count * camera.threshold_electrons)
    if term == "reset_loss":
        return camera.reset_loss * rate
    return 1.0 / count  # random_initial_state


def decide_noise_terms(camera: SpikeCamera, y_levels: Iterable[float] | np.ndarray, tolerance: float,
                       window: int = 41) -> list[NoiseDecision]:
    """Keep each noise term whose effect (noise_effect) at any of `y_levels` reaches `tolerance`.

    Pass the levels that matter for the scene (e.g. the 5th, 50th and 95th percentiles of a
    rendered frame): a dark pixel makes shot noise and dark current matter. Terms already off in
    `camera` stay off. The decisions are returned so they can be logged and recorded."""
    if not (isinstance(tolerance, (int, float)) and math.isfinite(tolerance) and tolerance >= 0):
        raise ValueError(f"tolerance={tolerance!r} must be a finite number >= 0")
    if isinstance(window, bool) or not isinstance(window, int) or window < 1:
        raise ValueError(f"window={window!r} must be a positive integer (steps)")
    levels = np.asarray(list(y_levels) if not isinstance(y_levels, np.ndarray) else y_levels, dtype=np.float64).ravel()
    if levels.size == 0:
        raise ValueError("y_levels is empty: give the scene's light levels (spikes per step)")
    if not np.all(np.isfinite(levels)) or levels.min() < 0:
        raise ValueError(f"y_levels must be finite and >= 0, got min {levels.min()!r}, max {levels.max()!r}")
    out = []
    for term in NOISE_TERMS:
        if getattr(camera, term) == NOISE_TERMS[term]:
            out.append(NoiseDecision(term, 0.0, False, "off in the camera"))
            continue
        effect = max(noise_effect(camera, term, float(y), window) for y in levels)
        keep = effect >= tolerance
        why = (f"effect {effect:.3g} {'>=' if keep else '<'} tolerance {tolerance:g} at y in "
               f"[{levels.min():.3g}, {levels.max():.3g}] over {window} steps")
        out.append(NoiseDecision(term, float(effect), keep, why))
    return out


def apply_noise_decisions(camera: SpikeCamera, decisions: Iterable[NoiseDecision]) -> SpikeCamera:
    """The camera with every term not kept switched off."""
    off = [d.term for d in decisions if not d.keep and getattr(camera, d.term) != NOISE_TERMS[d.term]]
    for t in off:
        log.info("noise term %s switched off (%s)", t, next(d.reason for d in decisions if d.term == t))
    return camera.without(*off) if off else camera


# ---- the quality presets -----------------------------------------------------------------------
#: The render knobs a quality preset sets (spikesim.render_settings.RenderSettings); a job's own
#: seed, resolution and device stay as they are.
QUALITY_RENDER_KNOBS = ("spp", "gt_spp", "variant", "keyframe_every")


@dataclass(frozen=True)
class SampleRule:
    """Samples per pixel per step chosen per scene from its Monte Carlo ratio (`monte_carlo_ratio`
    of probe renders): with a fresh render seed every step, Monte Carlo noise adds variance to a
    window's charge as shot noise does, and the loss of reconstruction quality it causes falls as
    1 / spp; the trade study measured the loss at 1 spp per unit of ratio (spikesim.preset_rule).
    The rule takes the fewest samples whose predicted loss is within the tolerance, at most
    `max_spp` (the most the study measured)."""

    loss_db_per_ratio: float
    """Aligned-PSNR loss at 1 spp per unit of Monte Carlo ratio (dB): the study's largest."""
    tolerance_db: float
    max_spp: int
    probes: int = 4
    """1-spp renders at step 0 (independent seeds) the ratio is read from."""

    def __post_init__(self) -> None:
        for what in ("loss_db_per_ratio", "tolerance_db"):
            v = getattr(self, what)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"sample rule: {what}={v!r} must be a finite number > 0")
        for what, least in (("max_spp", 1), ("probes", 2)):
            v = getattr(self, what)
            if isinstance(v, bool) or not isinstance(v, int) or v < least:
                raise ValueError(f"sample rule: {what}={v!r} must be an integer >= {least}")

    def predicted_loss_db(self, ratio: float, spp: int) -> float:
        return self.loss_db_per_ratio * ratio / spp

    def spp_for(self, ratio: float) -> int:
        """The fewest samples (at most max_spp) within the tolerance at `ratio`."""
        if isinstance(ratio, bool) or not isinstance(ratio, (int, float, np.floating)) or not (math.isfinite(ratio) and ratio >= 0):
            raise ValueError(f"Monte Carlo ratio {ratio!r} must be a finite number >= 0")
        # the fewest whole samples: the renderer's independent sampler takes any count, and the
        # loss falls as 1 / spp between the powers of two the study measured as at them
        need = math.ceil(self.loss_db_per_ratio * ratio / self.tolerance_db - 1e-12)
        return int(min(max(need, 1), self.max_spp))


def monte_carlo_ratio(probes: Any, threshold_electrons: float) -> float:
    """A scene's Monte Carlo ratio from `probes`, (n >= 2, H, W) renders of y (spikes per step) of
    one step at 1 spp with independent seeds: the Monte Carlo variance of a 1-spp render over the
    shot noise's variance at the same light, N_e mean(var) / mean(y), means over pixels (a
    per-step charge y has shot-noise variance y / N_e in threshold units). 0 for a black scene."""
    p = np.asarray(probes, dtype=np.float64)
    if p.ndim != 3 or p.shape[0] < 2 or p.shape[1] * p.shape[2] == 0:
        raise ValueError(f"probes of shape {p.shape}: expected (n >= 2, H, W) renders of one step")
    if not np.all(np.isfinite(p)) or np.any(p < 0):
        raise ValueError("the probe renders must be finite and >= 0 to read the Monte Carlo ratio")
    if not (math.isfinite(threshold_electrons) and threshold_electrons > 0):
        raise ValueError(f"threshold_electrons={threshold_electrons!r} must be > 0")
    mean_y = float(p.mean())
    if mean_y == 0.0:
        return 0.0
    return float(threshold_electrons * p.var(axis=0, ddof=1).mean() / mean_y)


@dataclass(frozen=True)
class QualitySettings(HoldsRenderSettings):
    """Every render and sensor knob the speed/accuracy study measured, as one validated record:
    the render knobs in a RenderSettings (declared once, there), the keyframe policy, the noise
    terms and the precision here. Build one with `QualitySettings.of(name, policy, spp=..., ...)`."""

    name: str
    render: RenderSettings
    """spp (each frame render), gt_spp (each ground-truth image), variant ("spectral", "mono" or
    "auto": mono for one light spectrum) and keyframe_every (the "fixed" policy's spacing)."""
    keyframe_policy: str
    """"every" (a render per step), "fixed" (every `keyframe_every` steps) or "adaptive"."""
    max_px_per_keyframe: float = 0.5
    """Adaptive: accumulated image motion allowed between keyframes (pixels)."""
    max_interval: int = 1024
    """Adaptive: longest keyframe interval (steps)."""
    noise: str = "all"
    """"all" (every term of the base camera) or "auto" (decide_noise_terms at `noise_tolerance`)."""
    noise_tolerance: float = 0.01
    precision: str = "float32"
    sample_rule: SampleRule | None = None
    """Samples per step chosen per scene from probe renders (`for_scene`); None: `spp` everywhere."""

    def __post_init__(self) -> None:
        if self.sample_rule is not None and not isinstance(self.sample_rule, SampleRule):
            raise ValueError(f"quality {self.name!r}: sample_rule={self.sample_rule!r} must be a SampleRule")
        if not isinstance(self.render, RenderSettings):
            raise ValueError(f"quality {self.name!r}: render={self.render!r} must be a RenderSettings")
        v = self.max_interval
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ValueError(f"quality {self.name!r}: max_interval={v!r} must be a positive integer")
        if self.variant not in VARIANTS:
            raise ValueError(f"quality {self.name!r}: variant={self.variant!r}; expected one of {VARIANTS}")
        if self.keyframe_policy not in KEYFRAME_POLICIES:
            raise ValueError(f"quality {self.name!r}: keyframe_policy={self.keyframe_policy!r}; expected one of {KEYFRAME_POLICIES}")
        if self.noise not in NOISE_POLICIES:
            raise ValueError(f"quality {self.name!r}: noise={self.noise!r}; expected one of {NOISE_POLICIES}")
        if self.precision not in PRECISIONS:
            raise ValueError(f"quality {self.name!r}: precision={self.precision!r}; expected one of {PRECISIONS}")
        if not (math.isfinite(self.max_px_per_keyframe) and self.max_px_per_keyframe > 0):
            raise ValueError(f"quality {self.name!r}: max_px_per_keyframe={self.max_px_per_keyframe!r} must be > 0")
        if not (math.isfinite(self.noise_tolerance) and self.noise_tolerance >= 0):
            raise ValueError(f"quality {self.name!r}: noise_tolerance={self.noise_tolerance!r} must be >= 0")

    @classmethod
    def of(cls, name: str, keyframe_policy: str, **knobs: Any) -> "QualitySettings":
        """A quality from flat knobs: render knobs (spp, gt_spp, variant, keyframe_every) go to its
        RenderSettings, the rest to the quality itself."""
        render, rest = split_render_knobs(knobs)
        try:
            settings = RenderSettings(**render)
        except ValueError as exc:
            raise ValueError(f"quality {name!r}: {exc}") from None
        return cls(name, settings, keyframe_policy, **rest)

    @classmethod
    def from_name(cls, name: str) -> "QualitySettings":
        if name not in PRESETS:
            raise ValueError(f"unknown quality {name!r}; expected one of {sorted(PRESETS)}")
        return PRESETS[name]

    def to_dict(self) -> dict[str, Any]:
        """Flat: the name, the render knobs it sets and its own knobs."""
        own = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in ("render", "sample_rule")}
        if self.sample_rule is not None:  # only then: the trade study's cached runs keep their keys
            own["sample_rule"] = dataclasses.asdict(self.sample_rule)
        return {**own, **self.render_kwargs()}

    def for_scene(self, mc_ratio: float) -> "QualitySettings":
        """This quality for a scene of Monte Carlo ratio `mc_ratio` (`monte_carlo_ratio` of its
        probes): the samples its rule chooses; the result has no rule left, so what it records is
        what rendered."""
        if self.sample_rule is None:
            return self
        render = self.render.replace(spp=self.sample_rule.spp_for(mc_ratio))
        return dataclasses.replace(self, render=render, sample_rule=None)

    # ---- what the pipeline stages take ---------------------------------------------------------
    def render_kwargs(self) -> dict[str, Any]:
        """The render knobs this quality sets, as keyword arguments for SceneRenderer (and
        RenderSettings.replace)."""
        return {k: getattr(self.render, k) for k in QUALITY_RENDER_KNOBS}

    def adaptive_policy(self) -> Any:
        from .render.adaptive import AdaptivePolicy
        return AdaptivePolicy(max_px_per_keyframe=self.max_px_per_keyframe, max_interval=self.max_interval)

    def camera(self, base: SpikeCamera, y_levels: Iterable[float] | np.ndarray | None = None
               ) -> tuple[SpikeCamera, list[NoiseDecision]]:
        """The sensor for this quality: `base` at this precision, with the noise terms the light
        levels cannot show switched off when noise="auto" (then y_levels is required)."""
        cam = base.replace(precision=self.precision)
        if self.noise == "all":
            return cam, [NoiseDecision(t, None, getattr(cam, t) != v, "quality keeps every term")
                         for t, v in NOISE_TERMS.items()]
        if y_levels is None:
            raise ValueError(f"quality {self.name!r} decides noise terms from the light: pass y_levels "
                             "(e.g. percentiles of a rendered frame)")
        decisions = decide_noise_terms(cam, y_levels, self.noise_tolerance)
        return apply_noise_decisions(cam, decisions), decisions

    def keyframes(self, renderer: Any, start: int, num_steps: int) -> Iterator[tuple[int, np.ndarray]]:
        """(step, frame) keyframes covering steps start .. start + num_steps - 1: adaptive ones end
        at the last step (for Simulator.stream_keyframes); fixed ones are `keyframe_every` apart and
        the last reaches or passes the last step (spikesim.keyframes.keyframe_steps). `renderer`
        needs render_step(step, spp) and motion_px(step)."""
        if isinstance(num_steps, bool) or not isinstance(num_steps, int) or num_steps < 1:
            raise ValueError(f"num_steps={num_steps!r} must be a positive integer")
        if self.keyframe_policy == "adaptive":
            from .render.adaptive import AdaptiveKeyframes
            yield from AdaptiveKeyframes(self.adaptive_policy(), spp=self.spp).keyframes(renderer, start, num_steps)
            return
        for s in keyframe_steps(start, num_steps, self.step_spacing):
            yield s, renderer.render_step(s, spp=self.spp)

    @property
    def step_spacing(self) -> int:
        """Steps between fixed keyframes: 1 for "every", `keyframe_every` for "fixed"."""
        return 1 if self.keyframe_policy == "every" else self.keyframe_every

    def simulate(self, sim: Any, renderer: Any, start: int, num_steps: int) -> Iterator[Any]:
        """Spike stream parts for exactly `num_steps` steps: a fixed spacing runs through
        Simulator.stream (one kernel call per chunk), adaptive keyframes through stream_keyframes."""
        if self.keyframe_policy == "adaptive":
            # scene steps -> the simulator's own step count (its stream may start at step 0)
            shift = sim.steps_done - start
            yield from sim.stream_keyframes((s + shift, f) for s, f in self.keyframes(renderer, start, num_steps))
            return
        frames = (f for _, f in self.keyframes(renderer, start, num_steps))
        done = 0
        for part in sim.stream(frames, keyframe_every=self.step_spacing, final=True):
            take = min(part.num_steps, num_steps - done)
            if take <= 0:
                break
            yield part.slice(0, take)
            done += take

    def record(self, decisions: Iterable[NoiseDecision] = ()) -> dict[str, Any]:
        """What a run stores in meta.json: the preset, its knobs and the noise decisions."""
        return {"quality": self.name, "settings": self.to_dict(),
                "noise_decisions": [d.to_dict() for d in decisions]}


#: Presets, chosen from the measured Pareto front (docs/tradeoff.md: the five LLR scenes under low
#: and normal light, 50 x 80 pixels, 3 windows of 41 steps, 2 shared cores). "err/floor" is a
#: run's per-pixel firing-rate error against the reference divided by the reference's own
#: sensor-noise floor (the same error between two sensor seeds), the worst of the 10 scene-lights.
#: - Every knob alone stays under 0.6 of the floor, but spp and keyframes compound: a keyframe's
#:   Monte Carlo noise is held for its whole interval, so sparse keyframes need more samples
#:   (spp 4 + adaptive 1 px: 1.61; spp 16 + adaptive 1 px: 0.81).
#: - float32 gave bit-identical streams to float64 in all 10 (err 0): float32 below `reference`.
#: - mono: err/floor <= 0.23, 0.5-1.1x the time at this size (spectral costs 1.0-1.5x mono at
#:   400 x 250, docs/scenes.md): "auto" (mono when the lights share one spectrum) below `reference`.
#: - noise terms: simulation is 1-2 % of the time, so no term's removal saved measurable time;
#:   removing any but reset_loss (err/floor <= 0.04) and threshold_mismatch (<= 0.13) changed the
#:   stream by 0.1-1.2 of the floor. So every term stays on, except that `draft` drops those whose
#:   effect at the scene's light is under 1 % (decide_noise_terms; in practice those two).
PRESETS: dict[str, QualitySettings] = {
    # The study's reference: a spectral render per step at 64 spp, float64, every noise term.
    "reference": QualitySettings.of("reference", spp=64, gt_spp=256, variant="spectral", keyframe_policy="every",
                                    noise="all", precision="float64"),
    # Fastest measured setting within half the noise floor everywhere: err/floor <= 0.43, speed-up
    # 4.3-39x (geometric mean 12x) at 50 x 80 (spp 16 + adaptive 0.5 px: 0.61; spp 4 + 0.25 px: 0.85).
    # (adaptive 1 px at 64 spectral spp ties at this size; fewer samples win at 400 x 250.)
    "balanced": QualitySettings.of("balanced", spp=16, gt_spp=64, variant="auto", keyframe_policy="adaptive",
                                   max_px_per_keyframe=0.25, noise="all", precision="float32"),
    # Fastest measured setting within the noise floor everywhere (never more different from the
    # reference than a second recording): err/floor <= 0.81, speed-up 14-41x (geometric mean 26x)
    # at 50 x 80 (spp 1 + adaptive 1 px: 3.1; spp 4 + adaptive 1 px: 1.6).
    "draft": QualitySettings.of("draft", spp=16, gt_spp=16, variant="auto", keyframe_policy="adaptive",
                                max_px_per_keyframe=1.0, noise="auto", noise_tolerance=0.01, precision="float32"),
}

def _fast() -> QualitySettings:
    """`fast`: the render knobs spikesim.preset_rule derives from the 400 x 250 study and its
    out-of-sample check set (their CSVs ship as spikesim/data/tradeoff_400.csv and
    rllr_check_200.csv; tests/test_preset_rule.py checks these equal the rule's output): a render
    every step with a fresh seed, the samples per step chosen per scene from 4 probe renders (its
    Monte Carlo ratio rho): the fewest whose predicted loss of aligned PSNR
    (TFP-205 and the shipped network), 0.048 dB x rho / spp, is within 0.2 dB
    (spikesim.preset_rule.FAST_TOLERANCE_DB says why 0.2), at most the 16 the study measured.
    The slope is the worst measured: a random RLLR scene at 200 x 125 (the study's own worst,
    Cook in normal light, is 0.027). Ground truth at 128 spp, the study's own reference ground
    truth (the error test asks up to 744 in normal light, more than that reference can vouch
    for). Mono where the lights share a spectrum (measured at 50 x 80: err/floor <= 0.23); every
    noise term (the study's runs kept them all). docs/tradeoff.md section 7."""
    return QualitySettings.of("fast", spp=16, gt_spp=128, variant="auto", keyframe_policy="every", noise="all",
                              precision="float32",
                              sample_rule=SampleRule(loss_db_per_ratio=0.048, tolerance_db=0.2, max_spp=16))


PRESETS["fast"] = _fast()
QUALITIES = tuple(PRESETS)

__all__ = ["QualitySettings", "SampleRule", "monte_carlo_ratio", "PRESETS", "QUALITIES", "NoiseDecision", "decide_noise_terms", "noise_effect",
           "apply_noise_decisions"]
