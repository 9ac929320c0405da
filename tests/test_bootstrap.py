"""The set-up installs the CPU build of torch explicitly (scripts/torch_cpu.sh): from the PyTorch
CPU index where it answers, else from the configured package sources, saying which."""
from __future__ import annotations

import http.server
import platform
import re
import subprocess
import sys
import threading
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_the_pin_is_a_cpu_build():
    pins = [line for line in (ROOT / "requirements/cpu.txt").read_text().splitlines() if line.startswith("torch")]
    assert pins and re.fullmatch(r"torch==\d+\.\d+\.\d+\+cpu", pins[0]), pins


def _plan(index: str) -> tuple[str, str]:
    r = subprocess.run(["bash", str(ROOT / "scripts/torch_cpu.sh"), sys.executable, "--print"],
                       env={"PATH": "/usr/bin:/bin", "SPIKESIM_TORCH_INDEX": index},
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    return r.stdout.strip(), r.stderr


@pytest.mark.skipif(platform.machine() != "x86_64", reason="the +cpu tag is dropped on aarch64")
def test_an_index_that_answers_is_used():
    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *a):
            pass

        def do_GET(self):  # any page: an index that answers
            self.send_response(200)
            self.end_headers()
            self.wfile.write(b"<html></html>")

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Quiet)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        index = f"http://127.0.0.1:{server.server_address[1]}/whl/cpu"
        command, said = _plan(index)
    finally:
        server.shutdown()
    assert f"--extra-index-url {index}" in command and "torch==" in command and "+cpu" in command
    assert "from the PyTorch CPU index" in said


def test_an_index_that_does_not_answer_falls_back_and_says_so(tmp_path):
    command, said = _plan("http://127.0.0.1:9/whl/cpu")  # port 9 (discard): refused at once
    assert "--extra-index-url" not in command and "torch==" in command
    assert "does not answer" in said and "configured package sources" in said
