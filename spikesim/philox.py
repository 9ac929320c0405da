"""Counter-based random numbers shared by the sensor backends: Philox4x32-7 in NumPy, the seed's
key, and the renewal shot noise's draw of a spike's threshold charge.

Both backends draw a spike's threshold charge from Philox4x32-7 counted by (pixel, spike index),
so without comparator noise the renewal camera's stream is bit-identical on every backend (as the
noiseless one is), and a spike that moves by a step (a knob, float32 against float64) does not
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


def threshold_charge_scale(threshold: np.ndarray | float, threshold_electrons: float, dtype: np.dtype) -> np.ndarray:
    """s = 1 / (3 sqrt(k)), k = threshold x N_e electrons: the Wilson-Hilferty cube's scale."""
    k = np.asarray(threshold, dtype=np.float64) * threshold_electrons
    return (1.0 / (3.0 * np.sqrt(k))).astype(dtype)


__all__ = ["PHILOX_M", "PHILOX_W", "PHILOX_ROUNDS", "THRESHOLD_CHARGE_TAG", "philox_key", "philox4x32_numpy",
           "popcount_normal_numpy", "threshold_charge_scale"]
