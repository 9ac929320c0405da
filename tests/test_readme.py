"""Every command block of the README runs, top to bottom, in a new folder, as a new user would run
them: the `bash` blocks line by line with the installed `spikesim` first on PATH, the `python`
blocks as scripts. Sizes are cut by flags appended to some lines (REDUCED: argparse takes the last
value of a flag); a line marked `# on a GPU` is skipped where there is none. The first block (the
set-up and test commands themselves) is not run here.

The whole README takes about 2.5 minutes on 2 shared cores, so it is `slow`; the fast suite checks that the
blocks parse and that every file a block reads is made by an earlier one or ships in the clone.
"""
from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
BIN = Path(sys.executable).parent

#: (pattern matched against a command line, flags appended to it): smaller frames, fewer scenes,
#: steps and training steps. The README says that this list exists.
SMALL = ["--height", "32", "--width", "48"]
REDUCED: list[tuple[str, list[str]]] = [
    (r"generate llr +--preset paper", ["--scenes", "fan", "--windows", "3", *SMALL, "--spp", "1", "--gt-spp", "2"]),
    (r"generate rllr +--preset paper", ["--count", "2", "--steps", "164", "--gt-stride", "41", *SMALL,
                                        "--spp", "1", "--gt-spp", "2"]),
    (r"generate rllr +--preset small", ["--count", "2", *SMALL]),
    (r"generate rllr .*--scales", ["--scales", "1"]),
    (r"sweep ", ["--scenes", "fan", "--levels", "2", "--windows", "1", *SMALL, "--spp", "1", "--gt-spp", "2"]),
    (r"generate scene .*--windows 21", ["--windows", "2"]),
    (r"train --config full", ["--max-steps", "2", "--num-windows", "3", "--crop", "16", "--batch-size", "1"]),
    (r"train --config tiny", ["--max-steps", "4"]),
    (r"golden --write", ["--seeds", "2"]),
    (r"render fan ", SMALL),
    (r"simulate --scene fan", ["--steps", "82", *SMALL]),
    (r"simulate --steps 4000", ["--steps", "410"]),
]
#: Files the blocks read that ship in the clone.
SHIPPED = ("tests/data/plain_scene",)


def readme_blocks(text: str | None = None) -> list[tuple[str, str]]:
    """(language, body) of every fenced block tagged bash or python, in order."""
    text = README.read_text() if text is None else text
    return [(m.group(1), m.group(2)) for m in re.finditer(r"^```(bash|python)\n(.*?)^```", text, re.S | re.M)]


def commands(body: str) -> list[str]:
    """A bash block's commands: continuation lines joined, comments and blank lines dropped."""
    joined = re.sub(r"\\\n\s*", " ", body)
    out = []
    for line in joined.splitlines():
        code = line.split(" #", 1)[0].strip() if not line.lstrip().startswith("#") else ""
        if code:
            out.append(line.strip())
    return out


def reduced(line: str) -> list[str] | None:
    """The argv to run for a README line (None: skipped, a GPU line without a GPU)."""
    code, _, comment = line.partition(" #")
    if "on a GPU" in comment and not _has_gpu():
        return None
    argv = shlex.split(code)
    for pattern, extra in REDUCED:
        if re.search(pattern, code):
            argv += extra
    return argv


def _has_gpu() -> bool:
    try:
        import drjit as dr
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:
        return False


def _blocks_to_run() -> list[tuple[str, str]]:
    blocks = readme_blocks()
    assert "scripts/test.sh" in blocks[0][1], "the first block is the set-up and test commands"
    return blocks[1:]


def test_blocks_parse_and_every_input_is_made_first():
    made: set[str] = set(SHIPPED)
    reads = re.compile(r"(?:(?<=\s)|^)((?:data|out|runs|tests/data)/[\w./-]+|[\w-]+\.(?:toml|npy|json|dat)\b)")
    for lang, body in _blocks_to_run():
        lines = commands(body) if lang == "bash" else [body]
        for line in lines:
            if lang == "bash":
                argv = reduced(line) or shlex.split(line.split(" #", 1)[0])
                assert argv[0] in ("spikesim", "python"), line
                outs = [argv[i + 1] for i, a in enumerate(argv[:-1]) if a in ("-o", "--out", "--write", "--preview")]
            else:
                outs = re.findall(r'"((?:out|data)/[\w./-]+)"', line)
            code = line.split(" #", 1)[0]
            for path in reads.findall(code):
                if path in outs or path.rstrip("/") in outs:
                    continue
                first = path.split("=")[-1]
                assert any(first == m or first.startswith(m.rstrip("/") + "/") for m in made), \
                    f"README line {line!r} reads {first}, which no earlier block makes"
            made.update(o.rstrip("/") for o in outs)
            made.update(re.findall(r"np\.save\('([^']+)'", code))


@pytest.mark.slow
@pytest.mark.timeout(1500)
def test_every_block_runs_top_to_bottom(tmp_path):
    for shipped in SHIPPED:
        shutil.copytree(ROOT / shipped, tmp_path / shipped)
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    env.pop("PYTHONPATH", None)
    for lang, body in _blocks_to_run():
        if lang == "python":
            r = subprocess.run([sys.executable, "-c", body], cwd=tmp_path, env=env, capture_output=True, text=True,
                               timeout=600)
            assert r.returncode == 0, f"README python block failed:\n{body}\n{r.stderr[-3000:]}"
            continue
        for line in commands(body):
            argv = reduced(line)
            if argv is None:
                continue
            r = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
            assert r.returncode == 0, f"README line failed (rc {r.returncode}): {line}\n{shlex.join(argv)}\n" \
                                      f"{r.stderr[-3000:]}"
