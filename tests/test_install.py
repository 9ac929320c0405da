"""A non-editable install works on its own: a wheel built from the checkout, installed into an
empty folder and run from outside the repository, finds every file it ships (model configs,
bundled scenes, the golden statistics) and runs.

The wheel is built without build isolation and installed with --no-deps, so the test needs no
network: the dependencies come from the running environment, the project's own code only from
the installed folder (each module's file is checked to lie there).
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("spikesim", "model", "pipelines", "scenes")
#: Suffixes of the package data pyproject.toml ships.
DATA_SUFFIXES = {".json", ".csv", ".xml", ".toml", ".png", ".jpg", ".ply", ".pt"}
#: What a build needs from the checkout besides the packages.
BUILD_FILES = ("pyproject.toml", "README.md", "LICENSE")


def source_data_files() -> set[str]:
    """Data files inside the checkout's packages, as paths relative to the checkout."""
    found = set()
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*"):
            if path.is_file() and path.suffix in DATA_SUFFIXES and "__pycache__" not in path.parts:
                found.add(path.relative_to(ROOT).as_posix())
    return found


def run(cmd: list[str], cwd: Path, env: dict[str, str], timeout: float = 300) -> subprocess.CompletedProcess:
    result = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, f"{' '.join(map(str, cmd))} -> {result.returncode}\n{result.stdout}\n{result.stderr}"
    return result


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(site folder, environment, working folder) of the project installed from a wheel."""
    if shutil.which("git") is None and not (ROOT / "pyproject.toml").exists():
        pytest.skip("no checkout to build from")
    pytest.importorskip("setuptools", reason="building the wheel needs setuptools (the `test` extra)")
    tmp = tmp_path_factory.mktemp("install")
    src = tmp / "src"  # a copy, so the build leaves nothing (build/, *.egg-info) in the checkout
    src.mkdir()
    for name in BUILD_FILES:
        shutil.copy2(ROOT / name, src / name)
    for package in PACKAGES:
        shutil.copytree(ROOT / package, src / package, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP")}
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    run([sys.executable, "-m", "pip", "wheel", str(src), "--no-deps", "--no-build-isolation", "-q",
         "-w", str(tmp / "wheel")], cwd=tmp, env=env)
    wheels = list((tmp / "wheel").glob("spikesim-*.whl"))
    assert len(wheels) == 1, wheels
    site = tmp / "site"
    run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-index", "-q", "--target", str(site),
         str(wheels[0])], cwd=tmp, env=env)
    env["PYTHONPATH"] = str(site)  # before the environment's site-packages (and any editable install)
    work = tmp / "work"
    work.mkdir()
    return site, env, work


def test_every_data_file_of_the_packages_is_installed(installed):
    site, _, _ = installed
    missing = sorted(rel for rel in source_data_files() if not (site / rel).is_file())
    assert not missing, f"not in the wheel: {missing}"
    assert (site / "model" / "configs" / "full.json").is_file()
    licences = list(site.glob("spikesim-*.dist-info/licenses/LICENSE"))
    assert licences and licences[0].read_text() == (ROOT / "LICENSE").read_text()


CHECK = textwrap.dedent("""
    import json, sys
    from pathlib import Path
    site = Path(sys.argv[1]).resolve()
    import spikesim, model, pipelines, scenes
    from model.config import CONFIG_DIR, available_configs, load_config
    from scenes import SCENES, scene_path
    from spikesim.render.scene import SceneFiles
    out = {"modules": {m.__name__: str(Path(m.__file__).resolve()) for m in (spikesim, model, pipelines, scenes)},
           "config_dir": str(Path(str(CONFIG_DIR)).resolve()), "configs": {}, "scenes": {}}
    for name in available_configs():
        out["configs"][name] = load_config(name).name
    import re
    for name in SCENES:
        files = SceneFiles.resolve(name)
        xml = files.xml.read_text()
        referenced = re.findall(r'name="filename"\\s+value="([^"]+)"', xml)
        out["scenes"][name] = {
            "files": [str(p) for p in (files.xml, files.motion, files.lights)],
            "referenced": {r: (files.xml.parent / r).is_file() for r in referenced},
            "lights": sorted(json.loads(files.lights.read_text())),
        }
    data = Path(spikesim.__file__).parent / "data"
    out["data"] = sorted(p.name for p in data.glob("*.json")) if data.is_dir() else []
    from spikesim.golden import PACKAGED_REFERENCE, load_reference
    out["golden"] = {"path": str(Path(PACKAGED_REFERENCE).resolve()), "statistics": sorted(load_reference())}
    from model.checkpoint import state_fingerprint
    from model.pretrained import PRETRAINED, load_pretrained, pretrained_path
    out["pretrained"] = {name: [str(pretrained_path(name).resolve()), state_fingerprint(load_pretrained(name)[0].state_dict())]
                         for name in PRETRAINED}
    from spikesim.render import SceneRenderer
    for name in SCENES:  # loadable: Mitsuba reads the XML, meshes and textures, one tiny frame
        y = SceneRenderer(name, light="low", resolution=(8, 12), spp=1, gt_spp=1, device="llvm").render_step(0)
        out["scenes"][name]["frame"] = [list(y.shape), float(y.mean())]
    print(json.dumps(out))
""")


@pytest.fixture(scope="module")
def checked(installed):
    site, env, work = installed
    (work / "check.py").write_text(CHECK)
    result = run([sys.executable, "-P", "check.py", str(site)], cwd=work, env=env)
    return json.loads(result.stdout.strip().splitlines()[-1])


def test_the_project_is_imported_from_the_install_not_the_checkout(installed, checked):
    site = installed[0].resolve()
    for name, path in checked["modules"].items():
        assert Path(path).is_relative_to(site), (name, path)
    assert Path(checked["config_dir"]).is_relative_to(site)


def test_the_shipped_weights_load_from_the_install(installed, checked):
    from model.pretrained import PRETRAINED
    assert sorted(checked["pretrained"]) == sorted(PRETRAINED) and "lrrep" in PRETRAINED
    for name, (path, fingerprint) in checked["pretrained"].items():
        assert Path(path).is_relative_to(installed[0].resolve()) and fingerprint == PRETRAINED[name].weights_sha256


def test_each_model_config_loads_by_name(checked):
    shipped = sorted(p.stem for p in (ROOT / "model" / "configs").glob("*.json"))
    assert sorted(checked["configs"]) == shipped and {"full", "tiny"} <= set(shipped)
    assert all(checked["configs"][name] for name in shipped)


def test_the_bundled_scenes_are_complete_and_load(installed, checked):
    site = installed[0].resolve()
    assert sorted(checked["scenes"]) == ["ball", "car", "cook", "fan", "rotate"]
    for name, scene in checked["scenes"].items():
        assert all(Path(p).is_relative_to(site) for p in scene["files"]), scene["files"]
        assert scene["referenced"] and all(scene["referenced"].values()), (name, scene["referenced"])
        assert {"normal", "low"} <= set(scene["lights"]), (name, scene["lights"])
        shape, mean = scene["frame"]
        assert shape == [8, 12] and mean > 0, (name, scene["frame"])


def test_the_golden_statistics_ship_where_the_checkout_has_them(checked):
    in_checkout = sorted(p.name for p in (ROOT / "spikesim" / "data").glob("*.json"))
    assert checked["data"] == in_checkout


def test_the_golden_reference_is_found_in_the_install(installed, checked):
    """`spikesim golden` compares with the packaged reference: it must be the installed copy."""
    assert Path(checked["golden"]["path"]).is_relative_to(installed[0].resolve()), checked["golden"]
    assert checked["golden"]["statistics"], "the packaged reference loaded empty"


def test_the_console_script_reports_its_version_and_simulates(installed):
    site, env, work = installed
    spikesim = site / "bin" / "spikesim"
    assert spikesim.is_file()
    from importlib import metadata
    version = run([sys.executable, "-P", str(spikesim), "--version"], cwd=work, env=env).stdout.strip()
    assert version == f"spikesim {metadata.version('spikesim')}"
    run([sys.executable, "-P", str(spikesim), "simulate", "--height", "8", "--width", "12", "--steps", "30",
         "--backend", "numpy", "--quiet", "-o", "s.dat"], cwd=work, env=env)
    info = json.loads(run([sys.executable, "-P", str(spikesim), "inspect", "s.dat", "--json"], cwd=work,
                          env=env).stdout)
    assert (info["num_steps"], info["height"], info["width"]) == (30, 8, 12) and info["spikes"] > 0


def test_the_demo_runs_from_the_install(installed):
    """The README's first job, shrunk: one bundled scene, one window, rendered, simulated,
    written as a dataset and reconstructed, all from the installed files."""
    site, env, work = installed
    run([sys.executable, "-P", str(site / "bin" / "spikesim"), "demo", "--out", "demo", "--scenes", "fan",
         "--windows", "1", "--workers", "1", "--device", "llvm", "--quiet"], cwd=work, env=env)
    scenes = sorted(p.name for p in (work / "demo" / "llr").iterdir() if p.is_dir())
    assert scenes == ["fan_low", "fan_normal"], scenes
    for scene in scenes:
        assert (work / "demo" / "llr" / scene / "spikes.dat").stat().st_size > 0
    rows = (work / "demo" / "metrics.csv").read_text().splitlines()
    assert len(rows) > 1 and "fan_low" in "\n".join(rows), rows
