"""Counter-based random numbers shared by the sensor backends: Philox4x32-7 in NumPy, the seed's
key, the per-step normals, and the renewal shot noise's draw of a spike's threshold charge.

Both backends draw every temporal noise term from it. Per-step terms (the shot noise's and the
comparator's normals) come from one call counted by (pixel, step // 4, high word of the group, 0):
word q of the call belongs to step 4 g + q, its low 16 bits give the shot noise's normal and its
high 16 bits the comparator's, each a Binomial(16, 1/2) standardised (`half_word_normals_numpy`).
So the realistic camera's stream is bit-identical on every backend, it does not depend on chunking
or on which streams share a launch, and the kernel needs no logarithm or sine.

Both backends draw a spike's threshold charge from Philox4x32-7 counted by (pixel, spike index),
so the renewal camera's stream is bit-identical on every backend as well, and a spike that moves by a step (a knob, float32 against float64) does not
change the charge of any later interval: the runs of a study share their shot noise.
"""
from __future__ import annotations

import numpy as np

# Philox4x32 constants (Salmon et al., "Parallel random numbers: as easy as 1, 2, 3", SC 2011).
PHILOX_M = (0xD2511F53, 0xCD9E8D57)
PHILOX_W = (0x9E3779B9, 0xBB67AE85)
PHILOX_ROUNDS = 7  # Dr.Jit's default; passes BigCrush (Manssen et al. 2012)
#: Fourth counter word of the threshold-charge draws: keeps them apart from the per-step draws
#: (counted by (pixel, step group, high word, 0)) of the same pixel.
THRESHOLD_CHARGE_TAG = 0x52454E57  # "RENW"
#: Steps served by one Philox call of per-step draws: a 32-bit word a step.
STEPS_PER_CALL = 4
_MASK32 = np.uint64(0xFFFFFFFF)


def philox_key(seed: int) -> tuple[int, int]:
    """The 64-bit Philox key of a stream's seed, as (hi, lo) words: the seed mixed with
    constants, so it differs from NumPy's own Philox streams of the same seed."""
    k = (int(seed) * 0x9E3779B97F4A7C15 + 0x5DEECE66D) % (1 << 64)
    return k >> 32, k & 0xFFFFFFFF


def philox4x32_numpy(key: tuple[int, int], counter: tuple, rounds: int = PHILOX_ROUNDS) -> tuple:
    """Philox4x32 on uint32 arrays (broadcast): `key` = (hi, lo) words, `counter` = four words.
    The same function as spikesim.sensor_drjit.philox4x32 (tested bit for bit)."""
    s0, s1, s2, s3 = (np.asarray(c, dtype=np.uint64) for c in counter)
    k0, k1 = np.uint64(key[0]), np.uint64(key[1])
    m0, m1 = np.uint64(PHILOX_M[0]), np.uint64(PHILOX_M[1])
    for _ in range(rounds):
        p0, p1 = s0 * m0, s2 * m1  # 32 x 32 -> 64-bit products, exact in uint64
        s0, s1, s2, s3 = ((p1 >> np.uint64(32)) ^ s1 ^ k0, p1 & _MASK32,
                          (p0 >> np.uint64(32)) ^ s3 ^ k1, p0 & _MASK32)
        k0, k1 = (k0 + np.uint64(PHILOX_W[0])) & _MASK32, (k1 + np.uint64(PHILOX_W[1])) & _MASK32
    return tuple(x.astype(np.uint32) for x in (s0, s1, s2, s3))


def popcount_normal_numpy(*words: np.ndarray) -> np.ndarray:
    """The popcount normal of 32 n random bits, float32: (popcount - 16 n) / sqrt(8 n), a
    Binomial(32 n, 1/2) with a normal's mean and variance exactly (excess kurtosis -1/(16 n))."""
    bits = sum(np.bitwise_count(np.asarray(w, np.uint32)).astype(np.int64) for w in words)
    n = len(words)
    return ((bits - 16 * n).astype(np.float32) * np.float32(1.0 / np.sqrt(8.0 * n)))


def step_words_numpy(key: tuple[int, int], pixels: np.ndarray, group: int) -> tuple:
    """The four per-step words of Philox call `group` (steps 4 group .. 4 group + 3) for `pixels`:
    counter (pixel, group low word, group high word, 0), as the Dr.Jit kernel counts it."""
    group = int(group)
    return philox4x32_numpy(key, (pixels, group & 0xFFFFFFFF, (group >> 32) & 0xFFFFFFFF, 0))


def half_word_normals_numpy(word: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(shot, comparator) normals of a step's 32-bit word, float32: (popcount - 8) / 2 of its low
    and of its high 16 bits, Binomial(16, 1/2) standardised: a normal's mean and variance exactly,
    17 levels in [-4, 4], excess kurtosis -1/8. What the normals feed is a sum over the many steps
    of an inter-spike interval (shot noise, N_e = 1000 electrons a threshold) or a jitter of 0.6 %
    of a threshold (comparator), where neither the levels nor the tails show: the golden
    statistics pass (docs/sensor.md). Drawing them so instead of by Box-Muller made the realistic
    CPU kernel 1.5x faster (docs/performance.md)."""
    w = np.asarray(word, dtype=np.uint32)
    lo = np.bitwise_count(w & np.uint32(0xFFFF)).astype(np.float32)
    hi = np.bitwise_count(w >> np.uint32(16)).astype(np.float32)
    return (lo - np.float32(8)) * np.float32(0.5), (hi - np.float32(8)) * np.float32(0.5)


def threshold_charge_scale(threshold: np.ndarray | float, threshold_electrons: float, dtype: np.dtype) -> np.ndarray:
    """s = 1 / (3 sqrt(k)), k = threshold x N_e electrons: the Wilson-Hilferty cube's scale."""
    k = np.asarray(threshold, dtype=np.float64) * threshold_electrons
    return (1.0 / (3.0 * np.sqrt(k))).astype(dtype)


__all__ = ["PHILOX_M", "PHILOX_W", "PHILOX_ROUNDS", "THRESHOLD_CHARGE_TAG", "STEPS_PER_CALL", "philox_key",
           "philox4x32_numpy", "popcount_normal_numpy", "step_words_numpy", "half_word_normals_numpy",
           "threshold_charge_scale"]
