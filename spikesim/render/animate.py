"""Apply a motion file to a loaded scene through `mi.traverse` parameter updates.

Never re-parses XML (docs/design.md section 4). Analytic shapes, instances and moving emitters expose
`<id>.to_world`, which is set to M(t) @ rest; meshes bake their transform into
`<id>.vertex_positions`, which are recomputed from the rest-pose vertices (and normals rotated
with them). Matrices enter Dr.Jit through `dr.make_opaque`, so a new pose per frame reuses the
compiled kernels instead of baking literals into new ones.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .backend import dr, mi
from .errors import MotionError
from .motion import MotionSpec

#: At most this many rest-pose points per object are used to measure motion in pixels.
MAX_SAMPLE_POINTS = 512


@dataclass
class _Target:
    id: str
    kind: str                 # "to_world" or "mesh"
    rest: np.ndarray          # (4, 4) rest to_world, or (N, 3) rest vertices
    normals: np.ndarray | None
    points: np.ndarray        # (K, 3) rest-pose world points that sample the object's extent


def _bbox_corners(shape) -> np.ndarray:
    bb = shape.bbox()
    lo, hi = np.array(bb.min, dtype=np.float64).ravel(), np.array(bb.max, dtype=np.float64).ravel()
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


class Animator:
    """Binds a MotionSpec to a scene's parameters; `apply(t)` poses every moving object."""

    def __init__(self, scene, params, motion: MotionSpec):
        self.params = params
        self.motion = motion
        shapes = {s.id(): s for s in scene.shapes()}
        self.targets: list[_Target] = []
        for target in motion.targets:
            tw, vp = f"{target}.to_world", f"{target}.vertex_positions"
            if vp in params:
                verts = np.array(params[vp], dtype=np.float64).reshape(-1, 3)
                nk = f"{target}.vertex_normals"
                normals = np.array(params[nk], dtype=np.float64).reshape(-1, 3) if nk in params else None
                if normals is not None and normals.size == 0:
                    normals = None
                step = max(1, len(verts) // MAX_SAMPLE_POINTS)
                self.targets.append(_Target(target, "mesh", verts, normals, verts[::step]))
            elif tw in params:
                rest = np.array(params[tw].matrix, dtype=np.float64).reshape(4, 4)
                pts = _bbox_corners(shapes[target]) if target in shapes else rest[None, :3, 3]
                self.targets.append(_Target(target, "to_world", rest, None, pts))
            else:
                movable = sorted({k.rsplit(".", 1)[0] for k in params.keys()
                                  if k.endswith(".to_world") or k.endswith(".vertex_positions")})
                raise MotionError(motion.source, f"moves object {target!r}, which the scene does not have "
                                                 f"(objects that can move: {movable})")
        self._last_t: float | None = None

    @property
    def moving(self) -> bool:
        return bool(self.targets)

    def apply(self, t: float) -> None:
        """Pose every moving object at time t (seconds on the motion file's clock)."""
        if not self.targets or t == self._last_t:
            return
        for tg in self.targets:
            m = self.motion.transform(tg.id, t)
            if tg.kind == "to_world":
                mat = mi.Matrix4f((m @ tg.rest).astype(np.float32))
                dr.make_opaque(mat)
                self.params[f"{tg.id}.to_world"] = mi.AffineTransform4f(mat)
            else:
                v = tg.rest @ m[:3, :3].T + m[:3, 3]
                self.params[f"{tg.id}.vertex_positions"] = mi.Float(v.astype(np.float32).ravel())
                if tg.normals is not None:
                    nrm = tg.normals @ np.linalg.inv(m[:3, :3])  # inverse transpose, row vectors
                    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
                    self.params[f"{tg.id}.vertex_normals"] = mi.Float(nrm.astype(np.float32).ravel())
        self.params.update()
        self._last_t = t

    def world_points(self, t: float, skip: tuple[str, ...] = ()) -> np.ndarray:
        """Sample points of every moving object at time t, (K, 3) world coordinates; the targets
        in `skip` (the camera: its points are not scene points) are left out."""
        out = []
        for tg in self.targets:
            if tg.id in skip:
                continue
            m = self.motion.transform(tg.id, t)
            out.append(tg.points @ m[:3, :3].T + m[:3, 3])
        return np.concatenate(out) if out else np.zeros((0, 3))


__all__ = ["Animator"]
