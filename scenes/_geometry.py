"""Procedural meshes with texture coordinates, written as binary PLY files Mitsuba reads.

Each builder returns (vertices (N, 3), faces (M, 3), uv (N, 2)); smooth shading normals come
from trimesh. Texture coordinates follow Mitsuba's bitmap convention: (0, 0) is the image's
top-left pixel.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import trimesh

Mesh = tuple[np.ndarray, np.ndarray, np.ndarray]


def write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray | None = None,
              smooth: bool = False) -> Path:
    """Binary little-endian PLY: x y z [nx ny nz] [u v], triangle faces."""
    v = np.asarray(vertices, dtype=np.float32)
    f = np.asarray(faces, dtype=np.int32)
    cols = [v]
    props = ["x", "y", "z"]
    if smooth:
        n = trimesh.Trimesh(v, f, process=False).vertex_normals.astype(np.float32)
        cols.append(n)
        props += ["nx", "ny", "nz"]
    if uv is not None:
        cols.append(np.asarray(uv, dtype=np.float32))
        props += ["u", "v"]
    data = np.ascontiguousarray(np.concatenate(cols, axis=1), dtype="<f4")
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(v)}"]
    header += [f"property float {p}" for p in props]
    header += [f"element face {len(f)}", "property list uchar int vertex_indices", "end_header"]
    path.parent.mkdir(parents=True, exist_ok=True)
    face_rec = np.zeros(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face_rec["n"], face_rec["i"] = 3, f
    with open(path, "wb") as fh:
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        fh.write(data.tobytes())
        fh.write(face_rec.tobytes())
    return path


def merge(*meshes: Mesh) -> Mesh:
    vs, fs, uvs, off = [], [], [], 0
    for v, f, uv in meshes:
        vs.append(v)
        fs.append(f + off)
        uvs.append(uv)
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs), np.concatenate(uvs)


def transformed(mesh: Mesh, rotation: np.ndarray | None = None, offset=(0.0, 0.0, 0.0)) -> Mesh:
    v, f, uv = mesh
    if rotation is not None:
        v = v @ np.asarray(rotation).T
    return v + np.asarray(offset), f, uv


def box(sx: float, sy: float, sz: float) -> Mesh:
    """Axis-aligned box centred at the origin; every face maps the whole texture."""
    vs, fs, uvs = [], [], []
    half = np.array([sx, sy, sz]) / 2
    for axis in range(3):
        for sign in (-1.0, 1.0):
            a, b = [i for i in range(3) if i != axis]
            quad = []
            for (p, q) in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                c = np.zeros(3)
                c[axis] = sign
                c[a], c[b] = p, q
                quad.append(c * half)
            quad = np.array(quad)
            n0 = len(vs) * 4
            # orient outward
            normal = np.zeros(3)
            normal[axis] = sign
            tri = [0, 1, 2, 0, 2, 3] if np.cross(quad[1] - quad[0], quad[2] - quad[0]) @ normal > 0 else [0, 2, 1, 0, 3, 2]
            vs.append(quad)
            fs.append(np.array(tri).reshape(2, 3) + n0)
            uvs.append(np.array([[0, 1], [1, 1], [1, 0], [0, 0]], dtype=float))
    return np.concatenate(vs), np.concatenate(fs), np.concatenate(uvs)


def cylinder(radius: float, length: float, segments: int = 48, side_uv=(0.5, 0.98)) -> Mesh:
    """Cylinder along +y from -length/2 to +length/2 (an axle). Caps map the texture planarly
    (x -> u, z -> v, as seen from -y); the side maps to one texel `side_uv` (a tread colour)."""
    ang = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([np.cos(ang), np.zeros_like(ang), np.sin(ang)], axis=1) * radius
    vs, fs, uvs = [], [], []
    for sign in (-1.0, 1.0):
        y = sign * length / 2
        centre = np.array([[0.0, y, 0.0]])
        pts = np.concatenate([centre, ring + [0, y, 0]])
        n0 = sum(len(v) for v in vs)
        idx = np.arange(segments)
        tri = np.stack([np.zeros(segments, int), 1 + idx, 1 + (idx + 1) % segments], axis=1)
        if sign > 0:
            tri = tri[:, [0, 2, 1]]
        vs.append(pts)
        fs.append(tri + n0)
        u = 0.5 + pts[:, 0] / (2 * radius) * (-sign)  # seen from outside the cap
        v = 0.5 - pts[:, 2] / (2 * radius)
        uvs.append(np.stack([u, v], axis=1))
    n0 = sum(len(v) for v in vs)
    side = np.concatenate([ring + [0, -length / 2, 0], ring + [0, length / 2, 0]])
    idx = np.arange(segments)
    a, b = idx, (idx + 1) % segments
    tri = np.concatenate([np.stack([a, a + segments, b], 1), np.stack([b, a + segments, b + segments], 1)])
    vs.append(side)
    fs.append(tri + n0)
    uvs.append(np.tile(np.asarray(side_uv, float), (len(side), 1)))
    return np.concatenate(vs), np.concatenate(fs), np.concatenate(uvs)


def revolve(profile: list[tuple[float, float]], segments: int = 64) -> Mesh:
    """Surface of revolution about +z of a (radius, z) polyline; u = angle, v = along profile."""
    prof = np.asarray(profile, dtype=float)
    m = len(prof)
    ang = np.linspace(0, 2 * np.pi, segments + 1)
    r, z = prof[:, 0], prof[:, 1]
    vs = np.stack([np.outer(np.cos(ang), r), np.outer(np.sin(ang), r), np.tile(z, (segments + 1, 1))], axis=-1)
    seg_len = np.concatenate([[0], np.cumsum(np.hypot(np.diff(r), np.diff(z)))])
    uu, vv = np.meshgrid(ang / (2 * np.pi), seg_len / max(seg_len[-1], 1e-9), indexing="ij")
    faces = []
    for i in range(segments):
        for j in range(m - 1):
            a, b, c, d = i * m + j, (i + 1) * m + j, (i + 1) * m + j + 1, i * m + j + 1
            faces += [[a, b, c], [a, c, d]]
    v, f = vs.reshape(-1, 3), np.array(faces)
    # wind outward (one-sided BSDFs are black from behind): a closed profile has positive volume
    if trimesh.Trimesh(v, f, process=False).volume < 0:
        f = f[:, [0, 2, 1]]
    return v, f, np.stack([uu.ravel(), vv.ravel()], axis=1)


def extrude_convex(profile_xz: list[tuple[float, float]], width: float, cap_uv_box: tuple[float, float, float, float],
                   rim_uv=(0.5, 0.6)) -> Mesh:
    """Prism of a convex (x, z) profile, extruded along y over [-width/2, width/2].

    The two side faces map the texture planarly over the profile's bounding box (u along +x,
    v = 0 at the top); the rim faces (roof, bonnet, bumpers) take the texel `rim_uv`.
    `cap_uv_box` = (xmin, xmax, zmin, zmax) is the box mapped to [0, 1]^2.
    """
    p = np.asarray(profile_xz, dtype=float)
    k = len(p)
    x0, x1, z0, z1 = cap_uv_box
    vs, fs, uvs = [], [], []
    for sign in (-1.0, 1.0):
        pts = np.stack([p[:, 0], np.full(k, sign * width / 2), p[:, 1]], axis=1)
        n0 = sum(len(v) for v in vs)
        tri = np.array([[0, i, i + 1] for i in range(1, k - 1)])
        # outward normal is sign * y; profile is CCW in (x, z) seen from -y
        if sign > 0:
            tri = tri[:, [0, 2, 1]]
        vs.append(pts)
        fs.append(tri + n0)
        uvs.append(np.stack([(p[:, 0] - x0) / (x1 - x0), 1 - (p[:, 1] - z0) / (z1 - z0)], axis=1))
    n0 = sum(len(v) for v in vs)
    rim = np.concatenate([vs[0], vs[1]])
    idx = np.arange(k)
    a, b = idx, (idx + 1) % k
    tri = np.concatenate([np.stack([a, b, a + k], 1), np.stack([b, b + k, a + k], 1)])
    vs.append(rim)
    fs.append(tri + n0)
    uvs.append(np.tile(np.asarray(rim_uv, float), (len(rim), 1)))
    return np.concatenate(vs), np.concatenate(fs), np.concatenate(uvs)


def fan_blades(n_blades: int, r_in: float, r_out: float, pitch_deg: float, span_deg: float, res: int = 12) -> Mesh:
    """Twisted fan blades in the x-z plane around +y (the rotation axis); single surfaces meant
    for a two-sided BSDF. Texture maps planarly (x -> u, z -> v over [-r_out, r_out])."""
    vs, fs, uvs = [], [], []
    for b in range(n_blades):
        base = 2 * np.pi * b / n_blades
        rs = np.linspace(r_in, r_out, res)
        ss = np.linspace(-0.5, 0.5, res)
        pts = []
        for r in rs:
            width = math.radians(span_deg) * (0.6 + 0.4 * (r - r_in) / (r_out - r_in))
            for s in ss:
                a = base + s * width
                twist = math.radians(pitch_deg) * (1.2 - 0.4 * (r - r_in) / (r_out - r_in))
                pts.append([r * math.cos(a), s * width * r * math.tan(twist), r * math.sin(a)])
        pts = np.array(pts)
        n0 = sum(len(v) for v in vs)
        for i in range(res - 1):
            for j in range(res - 1):
                a0, a1, b0, b1 = i * res + j, i * res + j + 1, (i + 1) * res + j, (i + 1) * res + j + 1
                fs.append(np.array([[a0, b0, b1], [a0, b1, a1]]) + n0)
        vs.append(pts)
        uvs.append(np.stack([0.5 + pts[:, 0] / (2 * r_out), 0.5 - pts[:, 2] / (2 * r_out)], axis=1))
    return np.concatenate(vs), np.concatenate(fs), np.concatenate(uvs)


def torus(major: float, minor: float) -> Mesh:
    """A ring in the x-z plane around +y (a fan guard); one texel of texture."""
    t = trimesh.creation.torus(major_radius=major, minor_radius=minor, major_sections=64, minor_sections=8)
    rot = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], float)  # z-axis ring -> y-axis ring
    v = np.asarray(t.vertices) @ rot.T
    return v, np.asarray(t.faces), np.full((len(v), 2), 0.5)


__all__ = ["write_ply", "merge", "transformed", "box", "cylinder", "revolve", "extrude_convex", "fan_blades",
           "torus", "Mesh"]
