"""The OpenAI-compatible client against ``transformers serve`` (a real server process) serving the tiny
random-weight Qwen2-VL fixture on CPU: the images reach the model (each 32 x 32 px image adds its 16 visual
tokens + 2 markers to the prompt tokens the server counts), usage comes back, and a wrong model name is a
non-retried 400 naming the pinned model.

Needs the serving extra (``pip install -e .[vlm-serve]``: fastapi, uvicorn, openai, accelerate) and
``probes.vlm.tiny``; skipped otherwise. Slow: the server loads torch and the model (~10-30 s)."""

from __future__ import annotations

import contextlib
import importlib.util
import os
import shutil
import socket
import subprocess
import time
import urllib.request
from pathlib import Path

import pytest
from PIL import Image

from probes.vlm.interface import Prompt
from probes.vlm.openai_client import OpenAIServerAnswerer, ServerConfig, ServerError

MISSING = [
    m for m in ("fastapi", "uvicorn", "openai", "accelerate", "psutil") if importlib.util.find_spec(m) is None
]
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(bool(MISSING), reason=f"transformers serve needs {MISSING} (extra vlm-serve)"),
    pytest.mark.skipif(
        importlib.util.find_spec("probes.vlm.tiny") is None, reason="probes.vlm.tiny not present"
    ),
]
IMAGE_TOKENS = 16 + 2
"""A 32 x 32 px image in the tiny Qwen2-VL: (32 / 4)^2 patches merged 2 x 2 = 16 tokens, + vision start/end."""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_client_through_transformers_serve(tmp_path: Path) -> None:
    from probes.vlm.tiny import tiny_model_dir

    model_dir = tiny_model_dir("qwen2_vl", 0, tmp_path / "tiny")
    exe = shutil.which("transformers") or str(Path(os.sys.executable).parent / "transformers")
    port = _free_port()
    proc = subprocess.Popen(
        [exe, "serve", str(model_dir), "--host", "127.0.0.1", "--port", str(port), "--device", "cpu"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env={**os.environ, "HF_HUB_OFFLINE": "1"},
    )
    try:
        deadline = time.time() + 180
        while True:
            with contextlib.suppress(OSError):  # not listening yet: poll again
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=2) as r:
                    if r.status == 200:
                        break
            if proc.poll() is not None or time.time() > deadline:
                pytest.fail(
                    f"transformers serve did not start: {proc.stderr.read().decode()[-2000:] if proc.stderr else ''}"
                )
            time.sleep(1)
        images = []
        for k in range(2):
            images.append(tmp_path / f"img{k}.png")
            Image.new("RGB", (32, 32), (90 * k, 30, 200)).save(images[-1])
        text = "What colour is it?\nA. red\nB. green\nC. blue\nD. grey"
        prompts = [
            Prompt(f"p{n}", tuple(images[:n]), text, ("red", "green", "blue", "grey")) for n in (0, 1, 2)
        ]
        answerer = OpenAIServerAnswerer(
            ServerConfig(
                base_url=f"http://127.0.0.1:{port}/v1",
                model=str(model_dir),
                concurrency=2,
                timeout_s=120,
                max_retries=1,
                max_tokens=4,
            )
        )
        gens = answerer.answer(prompts)
        t0, t1, t2 = (g.tokens_in for g in gens)
        assert (t1 - t0, t2 - t1) == (IMAGE_TOKENS, IMAGE_TOKENS)
        assert all(g.tokens_out is not None and 1 <= g.tokens_out <= 4 for g in gens)
        wrong = OpenAIServerAnswerer(
            ServerConfig(base_url=f"http://127.0.0.1:{port}/v1", model="nope", max_retries=3)
        )
        with pytest.raises(ServerError, match=r"HTTP 400: .*pinned.*not retried"):
            wrong.answer(prompts[:1])
        assert wrong.stats.requests == 1
    finally:
        proc.terminate()
        proc.wait(timeout=30)
