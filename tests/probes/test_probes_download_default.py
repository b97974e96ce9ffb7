"""`python train.py backbone=dinov2 task=gravity` — the command researchers type first — fetches missing weights
into the HF cache like timm and transformers do, and with HF_HUB_OFFLINE=1 fails at once with a clear message.

The hub is a real HTTP server on loopback (HF_ENDPOINT) that records what it is asked and answers 404, so the
test proves the download is attempted by default without reaching the internet.
"""

from __future__ import annotations

import http.server
import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DINOV2_REPO = "timm/vit_base_patch14_dinov2.lvd142m"


class _RecordingHub(http.server.BaseHTTPRequestHandler):
    requests: list[str] = []

    def _answer(self) -> None:
        type(self).requests.append(f"{self.command} {self.path}")
        self.send_response(404)
        self.send_header("Content-Length", "0")
        self.end_headers()

    do_GET = do_HEAD = _answer

    def log_message(self, *args) -> None:  # keep the test output clean
        pass


@pytest.fixture()
def local_hub() -> Iterator[tuple[str, list[str]]]:
    _RecordingHub.requests = []
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _RecordingHub)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}", _RecordingHub.requests
    finally:
        server.shutdown()
        server.server_close()


def _train(tmp_path: Path, endpoint: str, offline: bool) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("HF_", "HUGGINGFACE"))}
    env.update(HF_ENDPOINT=endpoint, HF_HOME=str(tmp_path / "hf"), WANDB_MODE="offline", HF_HUB_DISABLE_TELEMETRY="1")
    if offline:
        env["HF_HUB_OFFLINE"] = "1"
    cmd = [sys.executable, "train.py", "backbone=dinov2", "task=gravity", f"paths.root_dir={tmp_path}", "logger=csv"]
    return subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=300)


def test_train_py_downloads_missing_weights_by_default(tmp_path: Path, local_hub) -> None:
    endpoint, requests = local_hub
    proc = _train(tmp_path, endpoint, offline=False)
    assert proc.returncode != 0  # the local hub has no such repo
    asked = [r for r in requests if DINOV2_REPO in r]
    assert asked, f"no request for {DINOV2_REPO} reached the hub; requests: {requests}\n{proc.stderr[-2000:]}"
    assert any("model.safetensors" in r for r in asked), asked
    assert f"from {endpoint} failed" in proc.stderr and DINOV2_REPO in proc.stderr


def test_train_py_offline_fails_at_once_with_the_clear_message(tmp_path: Path, local_hub) -> None:
    endpoint, requests = local_hub
    proc = _train(tmp_path, endpoint, offline=True)
    assert proc.returncode != 0
    assert requests == []  # offline means no request at all
    assert "are not available locally" in proc.stderr
    assert "HF_HUB_OFFLINE=1" in proc.stderr and f"huggingface-cli download {DINOV2_REPO}" in proc.stderr
