"""Parse user asset references: ``<scheme>:<path>?<key>=<value>&...``.

Examples: ``file:/data/mug.obj?material=ceramic&up=y&scale=0.01``,
``ply:/captures/room.ply?up=y&scale=1.0``. Every reference takes ``name=<text>``: the
name shards and questions use (default: the file's stem), so no user path ever
enters a world state; the file itself is recorded as provenance (file name and
SHA-256), see :func:`file_provenance`. The path runs to the last ``?``; values
are plain text (no percent-decoding). Each loader names the keys it accepts and
their meaning; an unknown key, a repeated key or a malformed pair is an error.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class AssetUri:
    """A parsed reference: ``scheme`` ("file" or "ply"), the file ``path`` and the ``options`` as text."""

    scheme: str
    path: Path
    options: tuple[tuple[str, str], ...]

    def get(self, key: str, default: str) -> str:
        return dict(self.options).get(key, default)

    def display_name(self) -> str:
        """The ``name`` option, else the file's stem (``/data/duck.obj`` -> ``duck``): never a path."""
        name = self.get("name", self.path.stem)
        if not name or "/" in name or "\\" in name:
            raise ValueError(f"{self.scheme}:{self.path}: option name={name!r} must be non-empty text without '/'")
        return name

    def get_bool(self, key: str, default: bool) -> bool:
        """Option ``key`` as ``true``/``false``; anything else is an error naming the key and the value."""
        text = dict(self.options).get(key)
        if text is None:
            return default
        if text.lower() not in ("true", "false"):
            raise ValueError(f"{self.scheme}:{self.path}: option {key}={text!r} must be true or false")
        return text.lower() == "true"

    def get_float(self, key: str, default: float, low: float, high: float) -> float:
        """Option ``key`` as a finite float in [low, high]; errors name the key, the value and the range."""
        text = dict(self.options).get(key)
        if text is None:
            return default
        try:
            value = float(text)
        except ValueError:
            raise ValueError(f"{self.scheme}:{self.path}: option {key}={text!r} is not a number") from None
        if not (math.isfinite(value) and low <= value <= high):
            raise ValueError(f"{self.scheme}:{self.path}: option {key}={text} must be in [{low:g}, {high:g}]")
        return value


SCHEMES: tuple[str, ...] = ("file", "ply")


def is_asset_reference(text: str) -> bool:
    """Whether ``text`` is a user reference (``file:...`` or ``ply:...``) rather than a library name."""
    return str(text).partition(":")[0] in SCHEMES and ":" in str(text)


def file_provenance(path: Path) -> dict[str, str]:
    """Where a user asset came from, without its directory: ``{"file": name, "sha256": hex digest}``."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return {"file": path.name, "sha256": digest.hexdigest()}


def parse_asset_uri(text: str, allowed_keys: tuple[str, ...]) -> AssetUri:
    """Split ``scheme:path?k=v&k=v`` and check the keys against ``allowed_keys``."""
    scheme, sep, rest = text.partition(":")
    if not sep or not scheme or not rest:
        raise ValueError(f"asset reference {text!r} must look like 'scheme:/path/file?key=value&...'")
    path_text, _, query = rest.rpartition("?") if "?" in rest else (rest, "", "")
    if not path_text:
        raise ValueError(f"asset reference {text!r} has an empty path")
    options: dict[str, str] = {}
    for pair in filter(None, query.split("&")):
        key, eq, value = pair.partition("=")
        if not eq or not key:
            raise ValueError(f"asset reference {text!r}: option {pair!r} must be key=value")
        if key not in allowed_keys:
            raise ValueError(
                f"asset reference {text!r}: unknown option {key!r}; allowed options: {', '.join(allowed_keys)}"
            )
        if key in options:
            raise ValueError(f"asset reference {text!r}: option {key!r} given twice")
        options[key] = value
    return AssetUri(scheme, Path(path_text).expanduser(), tuple(sorted(options.items())))
