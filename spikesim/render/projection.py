"""Where a world point lands on the film: Mitsuba's `perspective` sensor as a pinhole in NumPy.

Used to check motion against renders (an object's projected position at step n) and to decide
how many sub-steps a step needs (motion per step in pixels).

Mitsuba's convention (src/sensors/perspective.cpp, look_at in core/transform.h): camera space
has +z forward, +x to the *left* and +y up; film column 0 is the left edge, row 0 the top.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera: camera-to-world matrix, horizontal field of view, film size."""

    to_world: np.ndarray  # (4, 4)
    x_fov_deg: float
    width: int
    height: int

    @classmethod
    def from_params(cls, params, sensor_id: str, width: int, height: int) -> "PinholeCamera":
        """Read the sensor's `to_world` and `x_fov` from `mi.traverse` parameters."""
        m = np.array(params[f"{sensor_id}.to_world"].matrix, dtype=np.float64).reshape(4, 4)
        fov = float(np.asarray(params[f"{sensor_id}.x_fov"]).ravel()[0])
        return cls(to_world=m, x_fov_deg=fov, width=width, height=height)

    def camera_space(self, points: np.ndarray) -> np.ndarray:
        """World points (..., 3) -> camera space (..., 3)."""
        inv = np.linalg.inv(self.to_world)
        p = np.asarray(points, dtype=np.float64)
        return p @ inv[:3, :3].T + inv[:3, 3]

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (..., 3) -> (pixel coordinates (..., 2) as (column, row) with pixel
        centres at +0.5, in-front mask). Points behind the camera get NaN."""
        c = self.camera_space(points)
        z = c[..., 2]
        front = z > 1e-9
        tx = math.tan(math.radians(self.x_fov_deg) / 2.0)
        ty = tx * self.height / self.width
        with np.errstate(divide="ignore", invalid="ignore"):
            col = 0.5 * self.width * (1.0 - c[..., 0] / (z * tx))
            row = 0.5 * self.height * (1.0 - c[..., 1] / (z * ty))
        uv = np.stack([col, row], axis=-1)
        uv[~front] = np.nan
        return uv, front

    def moved(self, transform: np.ndarray) -> "PinholeCamera":
        """The camera carried by a world transform (4, 4): a motion file's M(t) of the camera,
        applied to this pose as to the rest pose of any other object."""
        return dataclasses.replace(self, to_world=np.asarray(transform, dtype=np.float64) @ self.to_world)

    def rays(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World rays through pixel coordinates (..., 2) as (column, row), the inverse of
        `project`: (origins (..., 3), unit directions (..., 3))."""
        px = np.asarray(pixels, dtype=np.float64)
        tx = math.tan(math.radians(self.x_fov_deg) / 2.0)
        ty = tx * self.height / self.width
        d = np.stack([(1.0 - 2.0 * px[..., 0] / self.width) * tx, (1.0 - 2.0 * px[..., 1] / self.height) * ty,
                      np.ones(px.shape[:-1])], axis=-1)
        d = d @ self.to_world[:3, :3].T
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return np.broadcast_to(self.to_world[:3, 3], d.shape).copy(), d


__all__ = ["PinholeCamera"]
