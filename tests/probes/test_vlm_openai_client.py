"""The OpenAI-compatible client against a real server process (tests/fixtures/openai_stub_server.py): images
arrive decoded, answers come back in order, injected 500 / 429 / timeouts are retried, the concurrency bound
holds, a 4xx fails at once with the URL, status and body in the message, and the key never leaks."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from PIL import Image

from probes.vlm.interface import Prompt
from probes.vlm.openai_client import OpenAIServerAnswerer, ServerConfig, ServerError, from_config

SERVER = Path(__file__).resolve().parents[1] / "fixtures" / "openai_stub_server.py"
RED = {"A": 0, "B": 85, "C": 170, "D": 255}


@pytest.fixture()
def server(monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[..., str]]:
    """Starts the stub server with the given flags; returns its base URL (``http://127.0.0.1:<port>/v1``)."""
    procs: list[subprocess.Popen[str]] = []

    def start(*flags: str, env: dict[str, str] | None = None) -> str:
        import os

        proc = subprocess.Popen(
            [sys.executable, str(SERVER), "--port", "0", *flags],
            stdout=subprocess.PIPE,
            text=True,
            env={**os.environ, **(env or {})},
        )
        procs.append(proc)
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("PORT "), f"stub server did not start: {line!r}"
        return f"http://127.0.0.1:{int(line.split()[1])}/v1"

    yield start
    for proc in procs:
        proc.terminate()
        proc.wait(timeout=10)


def _stats(base_url: str) -> dict:
    with urllib.request.urlopen(base_url.removesuffix("/v1") + "/stats", timeout=5) as r:
        return json.loads(r.read())


def _prompts(tmp_path: Path, letters: str, images_per_item: int = 1) -> list[Prompt]:
    prompts = []
    for k, letter in enumerate(letters):
        paths = []
        for j in range(images_per_item):
            path = tmp_path / f"item{k}_{j}.png"
            Image.new("RGB", (8 + j, 6), (RED[letter] if j == 0 else 3, 10 * k % 256, 7)).save(path)
            paths.append(path)
        prompts.append(
            Prompt(
                idx=f"p{k}",
                images=tuple(paths),
                text=f"Question {k}?\nA. a\nB. b\nC. c\nD. d",
                options=("a", "b", "c", "d"),
            )
        )
    return prompts


def _answerer(base_url: str, **kw) -> OpenAIServerAnswerer:
    defaults = {"model": "stub", "concurrency": 1, "timeout_s": 5.0, "max_retries": 2, "backoff_s": 0.01}
    return OpenAIServerAnswerer(ServerConfig(base_url=base_url, **{**defaults, **kw}))


def test_answers_come_from_the_decoded_images_in_order(server, tmp_path: Path) -> None:
    url = server()
    prompts = _prompts(tmp_path, "BDAC", images_per_item=2)
    answerer = _answerer(url, concurrency=2)
    gens = answerer.answer(prompts)
    assert [g.text for g in gens] == [f"The answer is {x}." for x in "BDAC"]
    # the server decoded exactly the bytes of our files, both images of every item
    got = sorted(tuple(h) for h in _stats(url)["images"])
    want = sorted(tuple(hashlib.sha256(p.read_bytes()).hexdigest() for p in pr.images) for pr in prompts)
    assert got == want
    words = [len(p.text.split()) for p in prompts]
    assert [g.tokens_in for g in gens] == [w + 200 for w in words] and {g.tokens_out for g in gens} == {4}
    assert answerer.stats.tokens_in == sum(words) + 800 and answerer.stats.tokens_out == 16
    assert len({g.latency_s for g in gens}) == 1 and gens[0].latency_s > 0  # batch wall / batch size
    assert answerer.stats.requests == 4 and answerer.stats.retries == 0


def test_an_injected_500_and_429_are_retried(server, tmp_path: Path) -> None:
    url = server("--fail-first", "1", "--rate-limit-first", "1")
    answerer = _answerer(url, max_retries=2)
    gens = answerer.answer(_prompts(tmp_path, "CA"))
    assert [g.text for g in gens] == ["The answer is C.", "The answer is A."]
    assert answerer.stats.retries == 2 and answerer.stats.requests == 4  # 500, 429, then two answers
    assert _stats(url)["statuses"] == {"500": 1, "429": 1, "200": 2}


def test_a_request_past_the_timeout_is_retried(server, tmp_path: Path) -> None:
    url = server("--hang-first", "1", "--hang-s", "3")
    answerer = _answerer(url, timeout_s=0.5, max_retries=1)
    gens = answerer.answer(_prompts(tmp_path, "D"))
    assert gens[0].text == "The answer is D."
    assert answerer.stats.retries == 1 and answerer.stats.requests == 2
    assert 0.5 <= answerer.stats.request_latency_s[0] < 3.0  # the first attempt timed out, not waited out


def test_retries_exhausted_name_the_url_status_and_body(server, tmp_path: Path) -> None:
    url = server("--fail-first", "5")
    answerer = _answerer(url, max_retries=2)
    with pytest.raises(
        ServerError, match=r"gave up after 3 attempts; last: HTTP 500: .*injected failure 3"
    ) as e:
        answerer.answer(_prompts(tmp_path, "A"))
    assert url + "/chat/completions" in str(e.value) and e.value.status == 500
    assert _stats(url)["requests"] == 3


def test_a_4xx_is_not_retried(server, tmp_path: Path) -> None:
    url = server()
    answerer = _answerer(url, model="no-such-model", max_retries=3)
    with pytest.raises(ServerError, match=r"HTTP 404: .*no-such-model.* does not exist.*not retried"):
        answerer.answer(_prompts(tmp_path, "A"))
    assert _stats(url)["requests"] == 1 and answerer.stats.retries == 0


def test_connection_refused_is_retried_then_reported(tmp_path: Path) -> None:
    import socket

    with socket.socket() as s:  # a free port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    answerer = _answerer(f"http://127.0.0.1:{port}/v1", max_retries=1)
    with pytest.raises(ServerError, match=rf"127.0.0.1:{port}/v1/chat/completions.*2 attempts.*ConnectError"):
        answerer.answer(_prompts(tmp_path, "A"))
    assert answerer.stats.requests == 2


def test_concurrency_bound_is_respected(server, tmp_path: Path) -> None:
    url = server("--delay-s", "0.2")
    answerer = _answerer(url, concurrency=3)
    gens = answerer.answer(_prompts(tmp_path, "ABCDABCDA"))
    assert [g.text[-2] for g in gens] == list("ABCDABCDA")
    assert _stats(url)["max_in_flight"] == 3
    assert gens[0].latency_s * 9 >= 3 * 0.2  # three waves of 0.2 s at least


def test_api_key_from_the_environment_is_sent_and_never_shown(server, tmp_path: Path, monkeypatch) -> None:
    secret = "sk-test-0123456789"
    url = server("--api-key-env", "STUB_KEY", env={"STUB_KEY": secret})
    monkeypatch.setenv("NEWTPHYS_TEST_KEY", secret)
    answerer = from_config(
        {
            "kind": "openai_server",
            "name": "openai_server",
            "base_url": url,
            "model": "stub",
            "api_key_env": "NEWTPHYS_TEST_KEY",
            "concurrency": 1,
        }
    )
    assert answerer.answer(_prompts(tmp_path, "B"))[0].text == "The answer is B."
    assert secret not in json.dumps(answerer.describe()) and answerer.name == "openai-stub"
    monkeypatch.setenv("NEWTPHYS_TEST_KEY", "wrong-key")
    with pytest.raises(ServerError, match="HTTP 401") as e:
        answerer.answer(_prompts(tmp_path, "B"))
    assert "wrong-key" not in str(e.value)
    monkeypatch.delenv("NEWTPHYS_TEST_KEY")
    with pytest.raises(KeyError, match="NEWTPHYS_TEST_KEY"):
        answerer.answer(_prompts(tmp_path, "B"))


def test_backoff_is_exponential_capped_and_seeded() -> None:
    import random

    a = _answerer("http://127.0.0.1:1/v1", backoff_s=1.0, backoff_max_s=5.0)
    waits = [a._backoff_s(k, random.Random("0:x:0"), None) for k in range(5)]
    again = [a._backoff_s(k, random.Random("0:x:0"), None) for k in range(5)]
    assert waits == again  # seeded jitter
    for k, w in enumerate(waits):
        base = min(5.0, 2.0**k)
        assert 0.5 * base <= w < base
    assert a._backoff_s(0, random.Random(0), "3") == 3.0  # Retry-After honoured (above the jitter)


def test_bad_config_is_rejected_with_the_key() -> None:
    with pytest.raises(ValueError, match=r"concurrency=0, must be >= 1"):
        ServerConfig(base_url="http://x/v1", model="m", concurrency=0)
    with pytest.raises(KeyError, match=r"unknown keys \['temprature'\]"):
        ServerConfig.from_mapping({"base_url": "http://x/v1", "model": "m", "temprature": 0})


def test_the_hydra_config_builds_the_client() -> None:
    import hydra
    from omegaconf import OmegaConf

    cfg = OmegaConf.load(Path(__file__).resolve().parents[2] / "newtphys/conf/vlm/openai_server.yaml")
    cfg.model = "Qwen/Qwen2.5-VL-7B-Instruct"
    answerer = hydra.utils.instantiate(cfg)  # as the evaluate CLI builds a vlm= config
    assert isinstance(answerer, OpenAIServerAnswerer)
    assert answerer.config.temperature == 0.0 and answerer.config.max_tokens == 16
    assert answerer.url == "http://127.0.0.1:8000/v1/chat/completions"
    assert (
        answerer.name == "openai-Qwen_Qwen2.5-VL-7B-Instruct" and answerer.describe()["weights"] == "served"
    )
