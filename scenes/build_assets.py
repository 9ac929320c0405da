"""Build the bundled scenes' textures (PNG/JPEG) and meshes (PLY): `python -m scenes.build_assets`.

Deterministic: every scene draws from its own seeded generator, so a rebuild on the same library
versions reproduces the committed files. Sizes are kept small (the repository carries them):
noisy surfaces are 256-512 px JPEGs, flat artwork PNG, meshes a few thousand triangles.
Dimensions are real-world metres (docs/scenes.md lists them with the speeds).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from . import _geometry as G
from . import _textures as T

ROOT = Path(__file__).resolve().parent


def build_ball(out: Path, rng: np.random.Generator) -> None:
    T.save(T.wood_planks(rng, 512, 8, (196, 150, 100), (120, 80, 45)), out / "textures/floor_wood.jpg")
    T.save(T.painted_wall(rng, 1024, 512, (40, 90, 70), (225, 225, 215), "GYM 2"), out / "textures/wall.png")
    T.save(T.basketball(rng, 512, 256), out / "textures/basketball.png")
    T.save(T.volleyball(rng, 256, 128), out / "textures/volleyball.png")
    # a training cone: 23 cm tall on a 18 cm square-ish base (revolved)
    cone = G.revolve([(0.0, 0.23), (0.02, 0.225), (0.085, 0.02), (0.12, 0.02), (0.12, 0.0), (0.0, 0.0)], 48)
    G.write_ply(out / "meshes/cone.ply", *cone, smooth=False)


def build_car(out: Path, rng: np.random.Generator) -> None:
    T.save(T.asphalt(rng, 256), out / "textures/asphalt.jpg")
    T.save(T.stone(rng, 256, (165, 160, 150), (120, 115, 110)), out / "textures/pavement.jpg")
    T.save(T.brick_facade(rng, 1024, 512), out / "textures/facade.jpg")
    T.save(T.car_side(512, 256), out / "textures/car_side.png")
    T.save(T.car_glass(256, 128), out / "textures/car_glass.png")
    T.save(T.wheel(256), out / "textures/wheel.png")
    # A compact car, 4.3 m long, 1.75 m wide, 1.45 m tall (side profile in x-z, front at +x).
    body = [(-2.15, 0.30), (-2.05, 0.22), (2.05, 0.22), (2.15, 0.35), (2.12, 0.70), (1.70, 0.86),
            (-1.95, 0.92), (-2.13, 0.80)]
    G.write_ply(out / "meshes/car_body.ply", *G.extrude_convex(body, 1.75, (-2.15, 2.15, 0.22, 0.92), rim_uv=(0.5, 0.25)))
    cabin = [(-1.45, 0.91), (1.05, 0.87), (0.35, 1.42), (-1.05, 1.45)]
    G.write_ply(out / "meshes/car_cabin.ply", *G.extrude_convex(cabin, 1.52, (-1.45, 1.05, 0.87, 1.45), rim_uv=(0.5, 0.05)))
    # 0.32 m wheel radius (a 195/65 R15 tyre), 0.2 m wide; cap texture shows the rim
    G.write_ply(out / "meshes/wheel.ply", *G.cylinder(0.32, 0.20, 48, side_uv=(0.02, 0.5)), smooth=False)
    head = G.box(0.6, 0.25, 0.12)
    G.write_ply(out / "meshes/lamp_head.ply", *head)


def build_cook(out: Path, rng: np.random.Generator) -> None:
    T.save(T.tiles(rng, 512, 8, (228, 232, 235), (150, 150, 145)), out / "textures/tiles.png")
    T.save(T.stone(rng, 256, (70, 70, 75), (140, 135, 130)), out / "textures/counter.jpg")
    T.save(T.solid_noise(rng, 128, (35, 35, 38), (60, 60, 65), 2.0), out / "textures/pan.jpg")
    T.save(T.solid_noise(rng, 64, (200, 30, 25), (150, 15, 15), 6.0), out / "textures/tomato.jpg")
    T.save(T.solid_noise(rng, 64, (240, 120, 20), (200, 80, 10), 2.0), out / "textures/carrot.jpg")
    T.save(T.solid_noise(rng, 64, (60, 150, 40), (30, 100, 20), 3.0), out / "textures/pepper.jpg")
    T.save(T.wood_planks(rng, 256, 3, (205, 165, 110), (150, 105, 60)), out / "textures/board.jpg")
    # 26 cm frying pan, 5 cm deep, 2 mm walls (revolved profile, inside then outside)
    pan = G.revolve([(0.0, 0.004), (0.105, 0.004), (0.128, 0.05), (0.13, 0.05), (0.107, 0.0), (0.0, 0.0)], 64)
    G.write_ply(out / "meshes/pan.ply", *pan, smooth=True)
    G.write_ply(out / "meshes/pan_handle.ply", *G.box(0.20, 0.025, 0.018))
    G.write_ply(out / "meshes/carrot.ply", *G.box(0.016, 0.016, 0.016))
    ring = G.cylinder(0.02, 0.006, 24, side_uv=(0.5, 0.5))
    G.write_ply(out / "meshes/pepper.ply", *ring)
    G.write_ply(out / "meshes/board.ply", *G.box(0.36, 0.24, 0.02))
    G.write_ply(out / "meshes/counter.ply", *G.box(2.0, 0.7, 0.04))
    bottle = G.revolve([(0.0, 0.0), (0.035, 0.0), (0.035, 0.16), (0.012, 0.2), (0.012, 0.24), (0.0, 0.24)], 40)
    G.write_ply(out / "meshes/bottle.ply", *bottle, smooth=True)


def build_fan(out: Path, rng: np.random.Generator) -> None:
    T.save(T.wallpaper(rng, 512), out / "textures/wallpaper.png")
    T.save(T.wood_planks(rng, 256, 2, (170, 120, 80), (110, 70, 40)), out / "textures/desk.jpg")
    T.save(T.fan_hub(128), out / "textures/hub.png")
    blade_tex = T.solid_noise(rng, 128, (70, 130, 200), (50, 100, 170), 8.0)
    blade_tex[:, 60:68] = [235, 235, 235]  # a stripe across one blade marks the rotation
    T.save(blade_tex, out / "textures/blade.png")
    # 30 cm (12") desk fan: five blades from 4.5 to 15 cm, 25 degree pitch
    G.write_ply(out / "meshes/blades.ply", *G.fan_blades(5, 0.045, 0.15, 25.0, 48.0), smooth=True)
    G.write_ply(out / "meshes/hub.ply", *G.cylinder(0.045, 0.03, 40, side_uv=(0.1, 0.5)))
    G.write_ply(out / "meshes/housing.ply", *G.cylinder(0.065, 0.12, 40, side_uv=(0.5, 0.5)), smooth=False)
    G.write_ply(out / "meshes/guard.ply", *G.torus(0.165, 0.004))
    G.write_ply(out / "meshes/desk.ply", *G.box(1.4, 0.7, 0.03))


def build_rotate(out: Path, rng: np.random.Generator) -> None:
    T.save(T.disc_polar(rng, 512), out / "textures/disc.png")
    T.save(T.wood_planks(rng, 256, 4, (185, 140, 95), (125, 85, 50)), out / "textures/table.jpg")
    T.save(T.solid_noise(rng, 256, (200, 205, 210), (180, 185, 195), 12.0), out / "textures/wall.jpg")
    G.write_ply(out / "meshes/motor.ply", *G.cylinder(0.035, 0.07, 40, side_uv=(0.5, 0.5)), smooth=False)


BUILDERS = {"ball": build_ball, "car": build_car, "cook": build_cook, "fan": build_fan, "rotate": build_rotate}


def build(names: list[str] | None = None, root: Path = ROOT, seed: int = 2024) -> list[Path]:
    """Build the assets of `names` (default: all five scenes) under root/<name>/."""
    built = []
    for name in names or list(BUILDERS):
        # the stream depends on the scene, not on which scenes are built together
        rng = np.random.default_rng([seed, list(BUILDERS).index(name)])
        BUILDERS[name](root / name, rng)
        built.append(root / name)
    return built


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", help=f"scenes to build, of {sorted(BUILDERS)} (default: all)")
    ap.add_argument("--out", type=Path, default=ROOT, help="root folder (default: the scenes package)")
    args = ap.parse_args(argv)
    unknown = set(args.scenes) - set(BUILDERS)
    if unknown:
        ap.error(f"unknown scene(s) {sorted(unknown)}; choose from {sorted(BUILDERS)}")
    for p in build(args.scenes or None, args.out):
        print(p)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
