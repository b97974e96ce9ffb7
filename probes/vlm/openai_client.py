"""An :class:`~probes.vlm.interface.Answerer` for models behind an OpenAI-compatible server (vLLM, SGLang,
``transformers serve``, hosted APIs): ``POST <base_url>/chat/completions``.

One request per prompt: a single user message whose content is the prompt's images, in order, as base64
``data:`` URLs, then its text (the protocol: images first). ``temperature`` and ``max_tokens`` come from the
config (greedy, a letter needs a few tokens). Requests run on a thread pool of ``concurrency`` workers (the
server never sees more than that many at once); each has a timeout of ``timeout_s`` seconds and is retried
up to ``max_retries`` times on 408 / 429 / 5xx replies and on connection errors and timeouts, after an
exponential backoff ``backoff_s * 2**attempt`` (capped at ``backoff_max_s``, a 429's ``Retry-After`` is
honoured up to that cap) scaled by a jitter in [0.5, 1) drawn from a generator seeded by ``seed`` and the
item -- so a rerun waits the same. Any other 4xx is not retried. When the retries are exhausted the error
names the URL, the HTTP status and the start of the reply body.

The API key is read from the environment variable named by ``api_key_env`` when requests start; it is sent
as ``Authorization: Bearer ...`` and never logged, put in an error or in :meth:`describe`.

``latency_s`` of a :class:`Generation` follows the contract: the wall time of the ``answer`` call divided by
the number of prompts (the amortised cost per item at this concurrency); the wall time of each request
(retries included) and the token counts are kept in :attr:`OpenAIServerAnswerer.stats`.
"""

from __future__ import annotations

import base64
import logging
import os
import random
import re
import threading
import time
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import httpx

from probes.vlm.interface import Generation, Prompt

log = logging.getLogger(__name__)

RETRY_STATUSES: frozenset[int] = frozenset({408, 429, 500, 502, 503, 504})
"""HTTP statuses retried (any other 5xx is retried too); every other 4xx fails at once."""
BODY_EXCERPT_CHARS = 300
_MIME = {
    ".png": "image/png",
    ".jpg": "image/jpeg",
    ".jpeg": "image/jpeg",
    ".webp": "image/webp",
    ".gif": "image/gif",
}


class ServerError(RuntimeError):
    """A request failed for good: a non-retryable status, or retries exhausted."""

    def __init__(self, message: str, status: int | None = None, attempts: int = 1) -> None:
        super().__init__(message)
        self.status = status
        self.attempts = attempts


@dataclass(frozen=True)
class ServerConfig:
    """``newtphys/conf/vlm/openai_server.yaml``."""

    base_url: str
    """Up to and including the API version, e.g. ``http://127.0.0.1:8000/v1``."""
    model: str
    """The ``model`` field of each request (the name the server serves it under)."""
    api_key_env: str | None = None
    """Name of the environment variable that holds the API key (None: no key sent)."""
    concurrency: int = 8
    """Requests in flight at most."""
    timeout_s: float = 120.0
    """Per request (connect, read, write and pool), s."""
    max_retries: int = 5
    """Retries after the first attempt (0: no retry)."""
    backoff_s: float = 1.0
    """First backoff before the jitter, s; doubles per retry."""
    backoff_max_s: float = 30.0
    temperature: float = 0.0
    max_tokens: int = 16
    seed: int = 0
    """Seeds the backoff jitter (and is sent as the request's ``seed`` when ``send_seed``)."""
    send_seed: bool = False
    system_prompt: str | None = None
    extra_body: dict[str, Any] = field(default_factory=dict)
    """Merged into every request body (server-specific options, e.g. ``top_k``)."""

    def __post_init__(self) -> None:
        checks = [
            ("concurrency", self.concurrency >= 1, ">= 1"),
            ("timeout_s", self.timeout_s > 0, "> 0"),
            ("max_retries", self.max_retries >= 0, ">= 0"),
            ("backoff_s", self.backoff_s >= 0, ">= 0"),
            ("max_tokens", self.max_tokens >= 1, ">= 1"),
            ("base_url", self.base_url.startswith(("http://", "https://")), "an http(s):// URL"),
        ]
        for key, ok, allowed in checks:
            if not ok:
                raise ValueError(f"openai_server config: {key}={getattr(self, key)!r}, must be {allowed}")

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any]) -> ServerConfig:
        """From a plain mapping (a resolved Hydra node); ``kind`` and ``name`` are ignored, unknown keys fail."""
        known = {f.name for f in fields(ServerConfig)}
        data = {k: v for k, v in dict(cfg).items() if k not in ("kind", "name", "_target_")}
        unknown = sorted(set(data) - known)
        if unknown:
            raise KeyError(f"openai_server config: unknown keys {unknown}; valid keys: {sorted(known)}")
        if data.get("extra_body") is None:
            data.pop("extra_body", None)
        return ServerConfig(**data)


@dataclass
class ClientStats:
    """Counters over the life of one answerer (thread-safe through the answerer's lock)."""

    requests: int = 0
    """Attempts sent, retries included."""
    retries: int = 0
    failures: int = 0
    request_latency_s: list[float] = field(default_factory=list)
    """Per answered prompt: wall time from the first attempt to the reply, backoff included, s."""
    tokens_in: int = 0
    tokens_out: int = 0

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        lat = d.pop("request_latency_s")
        d["answered"] = len(lat)
        d["mean_request_latency_s"] = sum(lat) / len(lat) if lat else None
        d["max_request_latency_s"] = max(lat) if lat else None
        return d


def image_data_url(path: Path) -> str:
    """``data:<mime>;base64,<bytes>`` of an image file, bytes unchanged."""
    mime = _MIME.get(path.suffix.lower())
    if mime is None:
        raise ValueError(f"image {path}: unsupported suffix {path.suffix!r}; supported: {sorted(_MIME)}")
    if not path.is_file():
        raise FileNotFoundError(f"image {path} does not exist")
    return f"data:{mime};base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def chat_messages(prompt: Prompt, system_prompt: str | None = None) -> list[dict[str, Any]]:
    """The chat messages of one prompt: (system,) user = [images..., text]."""
    content: list[dict[str, Any]] = [
        {"type": "image_url", "image_url": {"url": image_data_url(Path(p))}} for p in prompt.images
    ]
    content.append({"type": "text", "text": prompt.text})
    messages: list[dict[str, Any]] = [{"role": "system", "content": system_prompt}] if system_prompt else []
    return [*messages, {"role": "user", "content": content}]


def _reply_text(body: dict[str, Any]) -> str:
    content = body["choices"][0]["message"].get("content")
    if content is None:
        return ""
    if isinstance(content, list):  # some servers return content parts
        return "".join(str(p.get("text", "")) for p in content if isinstance(p, dict))
    return str(content)


def _excerpt(text: str) -> str:
    text = " ".join(text.split())
    return text if len(text) <= BODY_EXCERPT_CHARS else text[:BODY_EXCERPT_CHARS] + " ..."


class OpenAIServerAnswerer:
    """Answers prompts through ``<base_url>/chat/completions`` (module docstring)."""

    def __init__(self, config: ServerConfig, name: str | None = None) -> None:
        self.config = config
        self.name = name or default_name(config.model)
        self.url = config.base_url.rstrip("/") + "/chat/completions"
        self.stats = ClientStats()
        self._lock = threading.Lock()
        self._client: httpx.Client | None = None

    def describe(self) -> dict[str, Any]:
        c = self.config
        return {
            "kind": "openai_server",
            "id": c.model,
            "revision": None,
            "dtype": None,
            "weights": "served",
            "base_url": c.base_url,
            "api_key_env": c.api_key_env,
            "temperature": c.temperature,
            "max_tokens": c.max_tokens,
            "system_prompt": c.system_prompt,
            "extra_body": dict(c.extra_body),
            "concurrency": c.concurrency,
        }

    # -- requests ---------------------------------------------------------------------------------------
    def _headers(self) -> dict[str, str]:
        headers = {"Content-Type": "application/json"}
        env = self.config.api_key_env
        if env:
            key = os.environ.get(env)
            if not key:
                raise KeyError(
                    f"openai_server config: api_key_env={env!r} but the environment variable is unset"
                )
            headers["Authorization"] = f"Bearer {key}"
        return headers

    def _body(self, prompt: Prompt) -> dict[str, Any]:
        c = self.config
        body: dict[str, Any] = {
            "model": c.model,
            "messages": chat_messages(prompt, c.system_prompt),
            "temperature": c.temperature,
            "max_tokens": c.max_tokens,
            "stream": False,
        }
        if c.send_seed:
            body["seed"] = c.seed
        return {**body, **c.extra_body}

    def _backoff_s(self, attempt: int, rng: random.Random, retry_after: str | None) -> float:
        c = self.config
        wait = min(c.backoff_max_s, c.backoff_s * 2.0**attempt) * (0.5 + 0.5 * rng.random())
        if retry_after is not None:
            try:
                wait = max(wait, min(c.backoff_max_s, float(retry_after)))
            except ValueError:
                pass  # an HTTP date: keep the exponential wait
        return wait

    def _count(self, **deltas: int) -> None:
        with self._lock:
            for k, v in deltas.items():
                setattr(self.stats, k, getattr(self.stats, k) + v)

    def request(self, prompt: Prompt, headers: dict[str, str]) -> tuple[str, int | None, int | None, float]:
        """(reply text, prompt tokens, completion tokens, wall time s) of one prompt, with retries."""
        assert self._client is not None
        c = self.config
        rng = random.Random(f"{c.seed}:{prompt.idx}:{prompt.rotation}")
        body = self._body(prompt)
        start = time.perf_counter()
        last = ""
        status: int | None = None
        for attempt in range(c.max_retries + 1):
            if attempt:
                self._count(retries=1)
            self._count(requests=1)
            retry_after = None
            try:
                r = self._client.post(self.url, json=body, headers=headers)
            except httpx.TransportError as e:  # connection refused / reset, timeouts
                status, last = None, f"{type(e).__name__}: {e or 'no detail'} (timeout {c.timeout_s} s)"
            else:
                status = r.status_code
                if status == 200:
                    try:
                        reply = r.json()
                        text = _reply_text(reply)
                    except (ValueError, KeyError, IndexError, TypeError) as e:
                        self._count(failures=1)
                        raise ServerError(
                            f"POST {self.url}: HTTP 200 but not a chat completion ({e!r}): "
                            f"{_excerpt(r.text)}",
                            status,
                            attempt + 1,
                        ) from None
                    usage = reply.get("usage") or {}
                    return (
                        text,
                        usage.get("prompt_tokens"),
                        usage.get("completion_tokens"),
                        time.perf_counter() - start,
                    )
                last = f"HTTP {status}: {_excerpt(r.text)}"
                if status not in RETRY_STATUSES and status < 500:
                    self._count(failures=1)
                    raise ServerError(
                        f"POST {self.url} (model {c.model!r}): {last} (not retried)", status, attempt + 1
                    )
                retry_after = r.headers.get("retry-after")
            if attempt < c.max_retries:
                wait = self._backoff_s(attempt, rng, retry_after)
                log.warning(
                    "POST %s item %s: %s; retry %d/%d in %.2f s",
                    self.url,
                    prompt.idx,
                    last,
                    attempt + 1,
                    c.max_retries,
                    wait,
                )
                time.sleep(wait)
        self._count(failures=1)
        raise ServerError(
            f"POST {self.url} (model {c.model!r}) item {prompt.idx}: gave up after "
            f"{c.max_retries + 1} attempts; last: {last}",
            status,
            c.max_retries + 1,
        )

    def answer(self, prompts: list[Prompt]) -> list[Generation]:
        """One generation per prompt, in order; raises :class:`ServerError` if any request fails for good."""
        if not prompts:
            return []
        c = self.config
        headers = self._headers()
        start = time.perf_counter()
        limits = httpx.Limits(max_connections=c.concurrency, max_keepalive_connections=c.concurrency)
        with httpx.Client(timeout=httpx.Timeout(c.timeout_s), limits=limits) as client:
            self._client = client
            try:
                with ThreadPoolExecutor(max_workers=min(c.concurrency, len(prompts))) as pool:
                    results = list(pool.map(lambda p: self.request(p, headers), prompts))
            finally:
                self._client = None
        per_item = (time.perf_counter() - start) / len(prompts)
        out = []
        for text, t_in, t_out, wall in results:
            with self._lock:
                self.stats.request_latency_s.append(wall)
                self.stats.tokens_in += t_in or 0
                self.stats.tokens_out += t_out or 0
            out.append(Generation(text=text, latency_s=per_item, tokens_in=t_in, tokens_out=t_out))
        return out


def default_name(model: str) -> str:
    """Results name of a served model: ``openai-<model>`` with path separators and spaces made ``_`` (it names
    a run directory)."""
    return "openai-" + re.sub(r"[^A-Za-z0-9._-]+", "_", model).strip("_")


def from_config(cfg: Mapping[str, Any]) -> OpenAIServerAnswerer:
    """The answerer of a ``vlm=openai_server`` config node (a plain mapping or resolved DictConfig); ``name``
    ``openai_server`` (the config's default) becomes :func:`default_name` of the model."""
    name = cfg.get("name")
    return OpenAIServerAnswerer(
        ServerConfig.from_mapping(cfg), name=name if name and name != "openai_server" else None
    )


def build_openai_answerer(**kwargs: Any) -> OpenAIServerAnswerer:
    """``_target_`` of ``newtphys/conf/vlm/openai_server.yaml``: the config's keys as keyword arguments."""
    return from_config(kwargs)
