"""Locating pretrained weights without hanging on the network.

Pretrained weights are read from (in order): an explicit ``weights_path``
(file or directory), the Hugging Face cache, or a download into that cache (as
timm and transformers do) unless ``HF_HUB_OFFLINE`` is set or the caller passes
``allow_download=False``. When none applies, or the download fails,
:class:`WeightsUnavailableError` is raised with a message saying how to provide
the weights. The cache location is computed at call time
from the environment (``HF_HUB_CACHE``, ``HF_HOME``, ``XDG_CACHE_HOME``), the
same rules huggingface_hub applies at import.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

logger = logging.getLogger(__name__)

_TRUE = {"1", "true", "yes", "on"}


class WeightsUnavailableError(FileNotFoundError):
    """Pretrained weights were requested but are not available locally."""


def hf_offline() -> bool:
    """True when ``HF_HUB_OFFLINE`` is set to a true value."""
    return os.environ.get("HF_HUB_OFFLINE", "").strip().lower() in _TRUE


def hf_cache_dir() -> Path:
    """The Hugging Face hub cache directory, resolved from the environment now."""
    if os.environ.get("HF_HUB_CACHE"):
        return Path(os.environ["HF_HUB_CACHE"]).expanduser()
    if os.environ.get("HF_HOME"):
        return Path(os.environ["HF_HOME"]).expanduser() / "hub"
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path("~/.cache").expanduser()
    return base / "huggingface" / "hub"


def missing_weights_message(backbone: str, repo_id: str, what: str) -> str:
    """The error text telling how to provide weights for ``backbone`` (HF repo ``repo_id``)."""
    return (
        f"pretrained weights for backbone {backbone!r} ({what} from Hugging Face repo {repo_id!r}) are not "
        f"available locally: not found in the HF cache {str(hf_cache_dir())!r} "
        f"(HF_HUB_OFFLINE={os.environ.get('HF_HUB_OFFLINE', '<unset>')}). Provide them in one of these ways: "
        f"(1) on a machine with network run `huggingface-cli download {repo_id}` and copy the cache to "
        f"{str(hf_cache_dir())!r} (or point HF_HOME / HF_HUB_CACHE at a cache that has it); "
        f"(2) pass a local copy: backbone.weights_path=/path/to/file_or_dir; "
        f"(3) let it download here: unset HF_HUB_OFFLINE (and keep backbone.allow_download true, the default). "
        f"backbone.pretrained=false builds the same architecture with RANDOM weights instead."
    )


def _download_failed(backbone: str, repo_id: str, what: str, error: Exception) -> str:
    from huggingface_hub import constants

    return (
        f"downloading {what} of {repo_id!r} for backbone {backbone!r} from {constants.ENDPOINT} failed: "
        f"{type(error).__name__}: {error}. " + missing_weights_message(backbone, repo_id, what)
    )


def resolve_hf_file(
    backbone: str,
    repo_id: str,
    filenames: tuple[str, ...],
    weights_path: str | os.PathLike[str] | None,
    allow_download: bool,
) -> Path:
    """Path of the first available file of ``filenames`` for ``repo_id``.

    ``weights_path`` may be the file itself or a directory holding one of ``filenames``.
    """
    if weights_path is not None:
        path = Path(weights_path).expanduser()
        if path.is_file():
            return path
        if path.is_dir():
            for name in filenames:
                if (path / name).is_file():
                    return path / name
        raise WeightsUnavailableError(
            f"weights_path={str(path)!r} for backbone {backbone!r} is neither a weights file nor a directory "
            f"holding one of {list(filenames)}"
        )
    from huggingface_hub import try_to_load_from_cache

    cache = hf_cache_dir()
    for name in filenames:
        found = try_to_load_from_cache(repo_id, name, cache_dir=cache)
        if isinstance(found, str) and Path(found).is_file():
            return Path(found)
    if allow_download and not hf_offline():
        from huggingface_hub import hf_hub_download

        logger.info("downloading %s/%s into %s", repo_id, filenames[0], cache)
        try:
            return Path(hf_hub_download(repo_id, filenames[0], cache_dir=cache))
        except Exception as e:  # network, auth, missing repo: say what failed and how to provide the weights
            raise WeightsUnavailableError(_download_failed(backbone, repo_id, filenames[0], e)) from e
    raise WeightsUnavailableError(missing_weights_message(backbone, repo_id, f"one of {list(filenames)}"))


def resolve_hf_snapshot(
    backbone: str,
    repo_id: str,
    required: tuple[str, ...],
    weights_path: str | os.PathLike[str] | None,
    allow_download: bool,
) -> Path:
    """Local directory of a snapshot of ``repo_id`` that holds every file in ``required``."""
    if weights_path is not None:
        path = Path(weights_path).expanduser()
        missing = [name for name in required if not (path / name).is_file()]
        if not path.is_dir() or missing:
            raise WeightsUnavailableError(
                f"weights_path={str(path)!r} for backbone {backbone!r} must be a directory holding "
                f"{list(required)}; missing: {missing if path.is_dir() else 'the directory itself'}"
            )
        return path
    from huggingface_hub import snapshot_download
    from huggingface_hub.errors import LocalEntryNotFoundError

    cache = hf_cache_dir()
    try:
        snapshot = Path(snapshot_download(repo_id, cache_dir=cache, local_files_only=True))
        if all((snapshot / name).is_file() for name in required):
            return snapshot
    except LocalEntryNotFoundError:
        pass
    if allow_download and not hf_offline():
        logger.info("downloading snapshot of %s into %s", repo_id, cache)
        try:
            return Path(snapshot_download(repo_id, cache_dir=cache))
        except Exception as e:  # network, auth, missing repo: say what failed and how to provide the weights
            raise WeightsUnavailableError(_download_failed(backbone, repo_id, "a snapshot", e)) from e
    raise WeightsUnavailableError(
        missing_weights_message(backbone, repo_id, f"a snapshot with {list(required)}")
    )
