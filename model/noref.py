"""No-reference measures of a reconstruction, for real recordings that have no ground truth.

Both are independent of the image's brightness scale (a method's gain is not what they judge):
- **flat-region noise**: the coefficient of variation (std / mean) of the image inside the flattest
  blocks of a reference image (lower is better). The flat blocks are chosen on a reference (e.g.
  TFP over the whole recording of a still scene), not on the image judged, so every method is
  measured on the same pixels and none can choose its own quietest corner.
- **edge sharpness**: the mean gradient magnitude on the reference's strongest edges, over the
  image's mean level (higher is sharper). Noise raises gradients too, so it is read together with
  the noise: `edge_to_noise` = sharpness / noise is the one number where both count.
"""
from __future__ import annotations

import numpy as np


def _blocks(shape: tuple[int, int], block: int) -> list[tuple[slice, slice]]:
    h, w = shape
    return [(slice(y, y + block), slice(x, x + block)) for y in range(0, h - block + 1, block)
            for x in range(0, w - block + 1, block)]


def gradient_magnitude(image: np.ndarray) -> np.ndarray:
    """|grad| by central differences (numpy.gradient), float64."""
    gy, gx = np.gradient(np.asarray(image, dtype=np.float64))
    return np.hypot(gx, gy)


#: The side of the tiles in which flat regions are sought (pixels): a panel's frames need at least this.
FLAT_BLOCK_PX = 16


def flat_blocks(reference: np.ndarray, block: int = FLAT_BLOCK_PX, fraction: float = 0.1) -> list[tuple[slice, slice]]:
    """The `fraction` of block x block tiles of `reference` with the least gradient energy
    relative to their level, among tiles that are not dark (level at least a tenth of the median
    tile's): where the scene is flat and lit, so what varies in an image there is noise."""
    if reference.ndim != 2 or min(reference.shape) < block:
        raise ValueError(f"reference must be a 2-D image of at least {block} x {block}, got {reference.shape}")
    if not 0 < fraction <= 1:
        raise ValueError(f"fraction must be in (0, 1], got {fraction}")
    grad = gradient_magnitude(reference)
    tiles = _blocks(reference.shape, block)
    levels = np.array([reference[t].mean() for t in tiles])
    lit = levels >= 0.1 * np.median(levels)
    score = np.array([grad[t].mean() for t in tiles]) / np.maximum(levels, 1e-12)
    order = [i for i in np.argsort(score) if lit[i]]
    return [tiles[i] for i in order[:max(1, int(round(fraction * len(tiles))))]]


def flat_noise(image: np.ndarray, blocks: list[tuple[slice, slice]]) -> float:
    """Mean over the blocks of std / mean of `image` (the coefficient of variation)."""
    image = np.asarray(image, dtype=np.float64)
    cvs = [image[t].std() / image[t].mean() for t in blocks if image[t].mean() > 0]
    return float(np.mean(cvs)) if cvs else float("nan")  # black there: no level to be noisy about


def edge_mask(reference: np.ndarray, fraction: float = 0.05) -> np.ndarray:
    """The `fraction` of pixels with the strongest gradient in `reference` (fewer where fewer
    pixels have any gradient at all: a flat pixel is never an edge)."""
    grad = gradient_magnitude(reference)
    return (grad >= np.quantile(grad, 1.0 - fraction)) & (grad > 0)


def edge_sharpness(image: np.ndarray, mask: np.ndarray) -> float:
    """Mean |grad| of `image` on the mask, over the image's mean level."""
    image = np.asarray(image, dtype=np.float64)
    level = image.mean()
    if not np.any(mask):  # a reference without edges: nothing to measure (NaN, and no NumPy warning)
        return float("nan")
    return float(gradient_magnitude(image)[mask].mean() / level) if level > 0 else 0.0


def no_reference_scores(image: np.ndarray, reference: np.ndarray, block: int = FLAT_BLOCK_PX) -> dict[str, float]:
    """{"flat_noise", "edge_sharpness", "edge_to_noise"} of `image`, regions chosen on `reference`.
    A reference without light is refused: every measure is a ratio to the light (round eight: an
    all-zero recording gave noise inf, sharpness NaN and NumPy warnings)."""
    if not np.any(np.asarray(reference) > 0):
        raise ValueError("the reference (TFP over the windows read) holds no spike: no-reference measures are "
                         "ratios to the light, and this recording has none in those windows")
    noise = flat_noise(image, flat_blocks(reference, block))
    sharp = edge_sharpness(image, edge_mask(reference))
    # a constant image (the `mean` floor) is 0 / 0: undefined, never a winning inf (round nine); its
    # flat blocks' std is float rounding (1e-17), not noise
    if np.ptp(np.asarray(image)) == 0:
        return {"flat_noise": 0.0 if np.isfinite(noise) else noise, "edge_sharpness": sharp,
                "edge_to_noise": float("nan")}
    ratio = sharp / noise if noise > 0 else (float("inf") if sharp > 0 else float("nan"))
    return {"flat_noise": noise, "edge_sharpness": sharp, "edge_to_noise": ratio}


__all__ = ["flat_blocks", "flat_noise", "edge_mask", "edge_sharpness", "gradient_magnitude", "no_reference_scores"]
