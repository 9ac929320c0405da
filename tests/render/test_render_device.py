"""The device-resident path: frames rendered on a Dr.Jit device feed the sensor there, with the
same bytes as the host round trip; memory stays flat; a GPU that is not here is one line; and,
where a GPU is present, CUDA renders agree with the CPU's within Monte Carlo noise."""
from __future__ import annotations

import numpy as np
import pytest

from render_testing import BALL, PLANE, SUN
from spikesim._drjit import has_cuda

MOVING = {"objects": [{"targets": ["ball"], "motions": [{"type": "translation", "velocity_mps": [200.0, 0, 0]}]}]}
SHAPES = BALL + PLANE.format(reflectance=0.5).replace("<scale value=\"50\"/>", "<scale value=\"50\"/><translate z=\"-0.5\"/>")
LIGHTS = {"normal": {"emitters": [SUN]}}


@pytest.fixture
def moving_scene(make_scene):
    return make_scene(SHAPES, lights=LIGHTS, motion=MOVING, integrator="path")


def test_device_frames_are_the_host_frames(moving_scene):
    from spikesim.render import SceneRenderer

    r = SceneRenderer(moving_scene, spp=2, seed=5, substeps=3)  # each frame: the mean of 3 renders
    assert r.device == ("cuda" if has_cuda() else "llvm")
    for step in (0, 7):
        host = r.render_step(step)
        dev = r.render_step_device(step)
        assert type(dev).__module__.startswith("drjit")
        np.testing.assert_array_equal(np.asarray(dev.numpy()).reshape(host.shape), host)


@pytest.mark.parametrize("k", [1, 3])
def test_render_to_sensor_without_the_host_gives_the_same_stream(moving_scene, k):
    from spikesim.camera import SpikeCamera
    from spikesim.render import SceneRenderer
    from spikesim.simulate import Simulator

    cam = SpikeCamera.realistic(height=25, width=40)
    r = SceneRenderer(moving_scene, spp=1, seed=2, camera=cam)
    host = Simulator(cam, backend=r.device, seed=4, chunk_steps=8).run(r.frames(0, 20, keyframe_every=k),
                                                                        keyframe_every=k)
    dev = Simulator(cam, backend=r.device, seed=4, chunk_steps=8).run(r.frames(0, 20, keyframe_every=k, device=True),
                                                                       keyframe_every=k)
    assert dev == host
    assert host.num_steps == (20 if k == 1 else 22)      # keyframes 0, 3, ..., 21 cover step 19
    assert host.counts().sum() > 0


def test_device_resident_memory_stays_flat(moving_scene):
    from spikesim.camera import SpikeCamera
    from spikesim.render import SceneRenderer
    from spikesim.simulate import Simulator

    def rss_mb() -> float:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) / 1024 for line in f if line.startswith("VmRSS:"))

    cam = SpikeCamera.realistic(height=25, width=40)
    r = SceneRenderer(moving_scene, spp=1, camera=cam)
    sim = Simulator(cam, backend=r.device, chunk_steps=16)
    parts = sim.stream(r.frames(0, 400, device=True), final=True)
    for _ in range(8):                                   # warm up: kernels compiled, caches filled
        next(parts)
    before = rss_mb()
    steps = sum(p.num_steps for p in parts)
    assert steps == 400 - 8 * 16
    assert rss_mb() - before < 20.0


@pytest.mark.skipif(has_cuda(), reason="a CUDA GPU is present")
@pytest.mark.parametrize("argv", [
    ["render", "fan", "--device", "cuda", "--steps", "0"],
    ["simulate", "--scene", "fan", "--device", "cuda", "--steps", "3"],
    ["generate", "llr", "--scenes", "fan", "--device", "cuda"],
    ["demo", "--device", "cuda"],
    ["tradeoff", "--scenes", "fan", "--device", "cuda"],
], ids=lambda a: a[0])
def test_device_cuda_without_a_gpu_is_one_line(argv, tmp_path, capsys):
    from pipelines.cli import main

    out = tmp_path / "out"
    flag = {"render": "--out", "simulate": "-o", "generate": "-o", "demo": "--out", "tradeoff": "-o"}[argv[0]]
    target = out / "s.dat" if argv[0] == "simulate" else out
    assert main([*argv, flag, str(target)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--device cuda" in err[0] and "no CUDA GPU" in err[0]
    assert not out.exists()


@pytest.mark.gpu
@pytest.mark.skipif(not has_cuda(), reason="needs a CUDA GPU")
@pytest.mark.parametrize("scene", ["ball", "car", "cook", "fan", "rotate"])
def test_cuda_renders_agree_with_the_cpu_within_monte_carlo_noise(scene):
    # Two CPU renders with different seeds give the Monte Carlo spread; the GPU render must differ
    # from a CPU render by no more than that (RMS), and their means must agree within 5 standard
    # errors of the mean difference.
    from spikesim.render import SceneRenderer

    def render(device: str, seed: int) -> np.ndarray:
        r = SceneRenderer(scene, light="normal", variant="mono", spp=16, seed=seed, resolution=(50, 80), device=device)
        return np.stack([r.render_step(s) for s in (100, 400)]).astype(np.float64)

    a, b, c = render("llvm", 0), render("llvm", 1), render("cuda", 0)
    spread = np.sqrt(np.mean((a - b) ** 2))
    assert spread > 0
    assert np.sqrt(np.mean((c - a) ** 2)) < 1.3 * spread
    se = np.std(a - b) / np.sqrt(a.size)
    assert abs(c.mean() - a.mean()) < 5 * max(se, 1e-12) + 1e-6 * a.mean()
