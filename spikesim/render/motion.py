"""Motion files: what moves in a scene and how, as rigid transforms of time.

A motion file (JSON, `motion.json` beside a scene's XML; schema in docs/scenes.md) lists objects,
each with the scene ids it moves (`targets`) and a list of motions. Every motion is a 4x4 world
transform M_i(t) applied to the object's rest pose (the pose in the XML); they compose in list
order, M(t) = M_n(t) ... M_1(t), and centres and pivots are rest-pose world coordinates, so a spin
about the object's own centre is listed before the translation that carries it.

Pure NumPy (float64): evaluating a motion never touches Mitsuba, so it is testable on its own and
the renderer can ask where an object is at any time (projection tests, sub-step estimation).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .errors import MotionError, read_json

MOTION_TYPES = ("rotation", "translation", "ballistic", "keyframes", "trajectory")
INTERPOLATIONS = ("step", "linear", "catmull_rom")
#: Speeds above this (m/s) are unit mistakes: faster than any projectile in everyday scenes.
MAX_SPEED_MPS = 1000.0
MAX_RPM = 1.0e6


# ---- small rigid-transform helpers ---------------------------------------------------------------
def translation(v: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = v
    return m


def rotation(axis: np.ndarray, angle_rad: float, center: np.ndarray | None = None) -> np.ndarray:
    """Rotation by `angle_rad` about the line through `center` along `axis` (Rodrigues' formula)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    r = np.eye(3) + math.sin(angle_rad) * k + (1.0 - math.cos(angle_rad)) * (k @ k)
    m = np.eye(4)
    m[:3, :3] = r
    if center is not None:
        c = np.asarray(center, dtype=np.float64)
        m[:3, 3] = c - r @ c
    return m


def _quat_from_axis_angle(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    a = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(a)
    if n == 0.0 or angle_rad == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    a = a / n
    return np.concatenate([[math.cos(angle_rad / 2)], math.sin(angle_rad / 2) * a])


def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _slerp(q0: np.ndarray, q1: np.ndarray, u: float) -> np.ndarray:
    """Spherical linear interpolation (Shoemake, SIGGRAPH 1985), shortest arc."""
    d = float(q0 @ q1)
    if d < 0.0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = q0 + u * (q1 - q0)
        return q / np.linalg.norm(q)
    th = math.acos(d)
    return (math.sin((1 - u) * th) * q0 + math.sin(u * th) * q1) / math.sin(th)


# ---- parsing helpers -----------------------------------------------------------------------------
class _Ctx:
    def __init__(self, path: Path):
        self.path = path

    def fail(self, where: str, problem: str) -> MotionError:
        return MotionError(self.path, f"{where}: {problem}")

    def number(self, where: str, value: Any, lo: float = -math.inf, hi: float = math.inf) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(where, f"must be a finite number, got {value!r}")
        if not lo <= value <= hi:
            raise self.fail(where, f"{value} is outside [{lo}, {hi}]")
        return float(value)

    def vec(self, where: str, value: Any, n: int = 3, nonzero: bool = False) -> np.ndarray:
        if not isinstance(value, (list, tuple)) or len(value) != n:
            raise self.fail(where, f"must be a list of {n} numbers, got {value!r}")
        v = np.array([self.number(f"{where}[{i}]", x) for i, x in enumerate(value)])
        if nonzero and not np.any(v):
            raise self.fail(where, "must not be the zero vector")
        return v

    def keys(self, where: str, data: dict, allowed: set[str]) -> None:
        unknown = set(data) - allowed - {"type", "comment"}
        if unknown:
            raise self.fail(where, f"unknown key(s) {sorted(unknown)}; allowed: {sorted(allowed)}")


def _velocity(ctx: _Ctx, where: str, d: dict) -> np.ndarray:
    """`velocity_mps` [vx, vy, vz], or `direction` with `speed_mps` or `speed_kmh`."""
    if "velocity_mps" in d:
        v = ctx.vec(f"{where}.velocity_mps", d["velocity_mps"])
    elif "direction" in d and ("speed_mps" in d or "speed_kmh" in d):
        u = ctx.vec(f"{where}.direction", d["direction"], nonzero=True)
        speed = (ctx.number(f"{where}.speed_mps", d["speed_mps"], 0.0) if "speed_mps" in d
                 else ctx.number(f"{where}.speed_kmh", d["speed_kmh"], 0.0) / 3.6)
        v = u / np.linalg.norm(u) * speed
    else:
        raise ctx.fail(where, "needs velocity_mps, or direction with speed_mps or speed_kmh")
    if np.linalg.norm(v) > MAX_SPEED_MPS:
        raise ctx.fail(where, f"speed {np.linalg.norm(v):.3g} m/s is above {MAX_SPEED_MPS} m/s: check the units")
    return v


# ---- motions -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Motion:
    """One motion component: `kind` and a function of time (s) returning a 4x4 world transform."""

    kind: str
    params: dict[str, Any]
    fn: Callable[[float], np.ndarray]

    def __call__(self, t: float) -> np.ndarray:
        return self.fn(t)


def _parse_rotation(ctx: _Ctx, where: str, d: dict) -> Motion:
    ctx.keys(where, d, {"axis", "rpm", "center", "phase_deg"})
    axis = ctx.vec(f"{where}.axis", d.get("axis"), nonzero=True)
    rpm = ctx.number(f"{where}.rpm", d.get("rpm"), -MAX_RPM, MAX_RPM)
    center = ctx.vec(f"{where}.center", d.get("center", [0.0, 0.0, 0.0]))
    phase = math.radians(ctx.number(f"{where}.phase_deg", d.get("phase_deg", 0.0)))
    omega = rpm * 2.0 * math.pi / 60.0  # rev/min -> rad/s
    return Motion("rotation", {"axis": axis.tolist(), "rpm": rpm, "center": center.tolist(), "phase_deg": math.degrees(phase)},
                  lambda t: rotation(axis, phase + omega * t, center))


def _parse_translation(ctx: _Ctx, where: str, d: dict) -> Motion:
    ctx.keys(where, d, {"velocity_mps", "direction", "speed_mps", "speed_kmh"})
    v = _velocity(ctx, where, d)
    return Motion("translation", {"velocity_mps": v.tolist()}, lambda t: translation(v * t))


def _parse_ballistic(ctx: _Ctx, where: str, d: dict) -> Motion:
    """Projectile under gravity, optionally bouncing on a floor with a coefficient of restitution."""
    ctx.keys(where, d, {"velocity_mps", "direction", "speed_mps", "speed_kmh", "gravity_mps2", "bounce"})
    v0 = _velocity(ctx, where, d)
    g = ctx.vec(f"{where}.gravity_mps2", d.get("gravity_mps2", [0.0, 0.0, -9.81]), nonzero=True)
    gmag = float(np.linalg.norm(g))
    down = g / gmag
    bounce = d.get("bounce")
    if bounce is None:
        return Motion("ballistic", {"velocity_mps": v0.tolist(), "gravity_mps2": g.tolist()},
                      lambda t: translation(v0 * t + 0.5 * g * t * t))
    if not isinstance(bounce, dict):
        raise ctx.fail(f"{where}.bounce", "must be an object with drop_m and restitution")
    ctx.keys(f"{where}.bounce", bounce, {"drop_m", "restitution"})
    drop = ctx.number(f"{where}.bounce.drop_m", bounce.get("drop_m"), 0.0)
    e = ctx.number(f"{where}.bounce.restitution", bounce.get("restitution"), 0.0, 1.0)
    u0 = float(-v0 @ down)              # upward speed
    v_side = v0 + u0 * down             # velocity component across gravity, unchanged by bounces

    def height(t: float) -> float:
        """Height above the floor contact (>= 0): free flight, then arcs shrinking by e."""
        t1 = (u0 + math.sqrt(u0 * u0 + 2.0 * gmag * drop)) / gmag  # first contact
        if t <= t1:
            return drop + u0 * t - 0.5 * gmag * t * t
        u = e * (gmag * t1 - u0)        # rebound speed = e * impact speed
        tau = t - t1
        for _ in range(200):
            arc = 2.0 * u / gmag
            if tau <= arc or arc < 1e-9:
                return max(0.0, u * tau - 0.5 * gmag * tau * tau) if arc >= 1e-9 else 0.0
            tau -= arc
            u *= e
        return 0.0

    def fn(t: float) -> np.ndarray:
        return translation(v_side * t - down * (height(t) - drop))

    return Motion("ballistic", {"velocity_mps": v0.tolist(), "gravity_mps2": g.tolist(),
                                "bounce": {"drop_m": drop, "restitution": e}}, fn)


def _interp_points(times: np.ndarray, pts: np.ndarray, t: float, mode: str) -> np.ndarray:
    """Position at t: step, linear, or cubic Hermite with Catmull-Rom tangents (non-uniform
    times; tangents from neighbouring keys, one-sided at the ends). Clamped outside the keys."""
    if t <= times[0]:
        return pts[0]
    if t >= times[-1]:
        return pts[-1]
    i = int(np.searchsorted(times, t, side="right") - 1)
    t0, t1 = times[i], times[i + 1]
    u = (t - t0) / (t1 - t0)
    if mode == "step":
        return pts[i]
    if mode == "linear" or len(times) == 2:
        return (1 - u) * pts[i] + u * pts[i + 1]

    def tangent(k: int) -> np.ndarray:
        a, b = max(k - 1, 0), min(k + 1, len(times) - 1)
        return (pts[b] - pts[a]) / (times[b] - times[a])

    h = t1 - t0
    m0, m1 = tangent(i) * h, tangent(i + 1) * h
    h00, h10, h01, h11 = 2 * u ** 3 - 3 * u ** 2 + 1, u ** 3 - 2 * u ** 2 + u, -2 * u ** 3 + 3 * u ** 2, u ** 3 - u ** 2
    return h00 * pts[i] + h10 * m0 + h01 * pts[i + 1] + h11 * m1


def _key_times(ctx: _Ctx, where: str, times: list[float]) -> np.ndarray:
    t = np.asarray(times, dtype=np.float64)
    if len(t) < 1 or np.any(np.diff(t) <= 0):
        raise ctx.fail(where, f"key times must be strictly increasing, got {times}")
    return t


def _parse_keyframes(ctx: _Ctx, where: str, d: dict) -> Motion:
    ctx.keys(where, d, {"interpolation", "keys", "pivot"})
    mode = d.get("interpolation", "linear")
    if mode not in INTERPOLATIONS:
        raise ctx.fail(f"{where}.interpolation", f"{mode!r}; expected one of {INTERPOLATIONS}")
    keys = d.get("keys")
    if not isinstance(keys, list) or not keys:
        raise ctx.fail(f"{where}.keys", "must be a non-empty list of {t, translate, rotate_axis, rotate_deg, scale}")
    pivot = ctx.vec(f"{where}.pivot", d.get("pivot", [0.0, 0.0, 0.0]))
    ts, trans, quats, scales = [], [], [], []
    for i, k in enumerate(keys):
        kw = f"{where}.keys[{i}]"
        if not isinstance(k, dict):
            raise ctx.fail(kw, "must be an object")
        ctx.keys(kw, k, {"t", "translate", "rotate_axis", "rotate_deg", "scale"})
        ts.append(ctx.number(f"{kw}.t", k.get("t")))
        trans.append(ctx.vec(f"{kw}.translate", k.get("translate", [0.0, 0.0, 0.0])))
        axis = ctx.vec(f"{kw}.rotate_axis", k.get("rotate_axis", [0.0, 0.0, 1.0]), nonzero=True)
        quats.append(_quat_from_axis_angle(axis, math.radians(ctx.number(f"{kw}.rotate_deg", k.get("rotate_deg", 0.0)))))
        s = k.get("scale", 1.0)
        sv = ctx.vec(f"{kw}.scale", s) if isinstance(s, list) else np.full(3, ctx.number(f"{kw}.scale", s))
        if np.any(sv <= 0):
            raise ctx.fail(f"{kw}.scale", "must be positive")
        scales.append(sv)
    times = _key_times(ctx, f"{where}.keys", ts)
    trans_a, scale_a = np.array(trans), np.array(scales)

    def fn(t: float) -> np.ndarray:
        p = _interp_points(times, trans_a, t, mode)
        s = _interp_points(times, scale_a, t, "step" if mode == "step" else "linear")
        if t <= times[0] or len(times) == 1:
            q = quats[0]
        elif t >= times[-1]:
            q = quats[-1]
        else:
            i = int(np.searchsorted(times, t, side="right") - 1)
            u = 0.0 if mode == "step" else (t - times[i]) / (times[i + 1] - times[i])
            q = _slerp(quats[i], quats[i + 1], u)
        m = np.eye(4)
        m[:3, :3] = _quat_to_matrix(q) * s[None, :]
        return translation(p + pivot) @ m @ translation(-pivot)

    return Motion("keyframes", {"interpolation": mode, "keys": keys, "pivot": pivot.tolist()}, fn)


def _parse_trajectory(ctx: _Ctx, where: str, d: dict) -> Motion:
    ctx.keys(where, d, {"interpolation", "points"})
    mode = d.get("interpolation", "catmull_rom")
    if mode not in INTERPOLATIONS:
        raise ctx.fail(f"{where}.interpolation", f"{mode!r}; expected one of {INTERPOLATIONS}")
    pts = d.get("points")
    if not isinstance(pts, list) or len(pts) < 2:
        raise ctx.fail(f"{where}.points", "must list at least two [t, dx, dy, dz] points")
    rows = np.array([ctx.vec(f"{where}.points[{i}]", p, n=4) for i, p in enumerate(pts)])
    times = _key_times(ctx, f"{where}.points", list(rows[:, 0]))
    disp = rows[:, 1:]
    return Motion("trajectory", {"interpolation": mode, "points": rows.tolist()},
                  lambda t: translation(_interp_points(times, disp, t, mode)))


_PARSERS = {"rotation": _parse_rotation, "translation": _parse_translation, "ballistic": _parse_ballistic,
            "keyframes": _parse_keyframes, "trajectory": _parse_trajectory}


@dataclass(frozen=True)
class ObjectMotion:
    """The motion of one rigid object, shared by every scene shape in `targets`."""

    targets: tuple[str, ...]
    motions: tuple[Motion, ...]

    def transform(self, t: float) -> np.ndarray:
        """World transform (4x4, float64) that takes the rest pose to the pose at time t."""
        m = np.eye(4)
        for motion in self.motions:
            m = motion(t) @ m
        return m


@dataclass(frozen=True)
class MotionSpec:
    """A parsed motion file. Time t (s) of step n at fraction f of its readout period is
    start_time_s + (n + f) * readout_period_s."""

    objects: tuple[ObjectMotion, ...]
    start_time_s: float = 0.0
    source: Path | None = None

    @property
    def targets(self) -> tuple[str, ...]:
        return tuple(t for o in self.objects for t in o.targets)

    def transform(self, target: str, t: float) -> np.ndarray:
        for o in self.objects:
            if target in o.targets:
                return o.transform(t)
        raise KeyError(target)

    def describe(self) -> dict[str, Any]:
        return {"source": str(self.source) if self.source else None, "start_time_s": self.start_time_s,
                "objects": [{"targets": list(o.targets), "motions": [{"type": m.kind, **m.params} for m in o.motions]}
                            for o in self.objects]}

    @classmethod
    def static(cls) -> "MotionSpec":
        return cls(objects=())


def parse_motion(data: Any, path: str | Path = "<motion>") -> MotionSpec:
    """Validate a motion document (already decoded JSON)."""
    ctx = _Ctx(Path(path))
    if not isinstance(data, dict):
        raise ctx.fail("top level", "must be an object with 'objects'")
    ctx.keys("top level", data, {"version", "start_time_s", "objects", "description"})
    if data.get("version", 1) != 1:
        raise ctx.fail("version", f"unsupported motion file version {data.get('version')!r} (expected 1)")
    start = ctx.number("start_time_s", data.get("start_time_s", 0.0))
    objs = data.get("objects", [])
    if not isinstance(objs, list):
        raise ctx.fail("objects", "must be a list")
    out, seen = [], set()
    for i, o in enumerate(objs):
        where = f"objects[{i}]"
        if not isinstance(o, dict):
            raise ctx.fail(where, "must be an object")
        ctx.keys(where, o, {"targets", "motions"})
        targets = o.get("targets")
        if not isinstance(targets, list) or not targets or not all(isinstance(t, str) for t in targets):
            raise ctx.fail(f"{where}.targets", "must be a non-empty list of scene object ids")
        dup = seen.intersection(targets)
        if dup:
            raise ctx.fail(f"{where}.targets", f"{sorted(dup)} already move in an earlier object")
        seen.update(targets)
        motions = o.get("motions")
        if not isinstance(motions, list) or not motions:
            raise ctx.fail(f"{where}.motions", "must be a non-empty list")
        parsed = []
        for j, m in enumerate(motions):
            mw = f"{where}.motions[{j}]"
            if not isinstance(m, dict) or m.get("type") not in MOTION_TYPES:
                raise ctx.fail(mw, f"type must be one of {MOTION_TYPES}, got {m.get('type') if isinstance(m, dict) else m!r}")
            parsed.append(_PARSERS[m["type"]](ctx, mw, m))
        out.append(ObjectMotion(tuple(targets), tuple(parsed)))
    return MotionSpec(objects=tuple(out), start_time_s=start, source=Path(path))


def load_motion(path: str | Path) -> MotionSpec:
    """Read and validate a motion file."""
    path = Path(path)
    data = read_json(path, MotionError, "motion file")
    return parse_motion(data, path)


__all__ = ["MotionSpec", "ObjectMotion", "Motion", "load_motion", "parse_motion", "rotation", "translation",
           "MOTION_TYPES", "INTERPOLATIONS"]
