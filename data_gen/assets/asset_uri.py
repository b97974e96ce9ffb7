"""Parse user asset references: ``<scheme>:<path>?<key>=<value>&...``.

Examples: ``file:/data/mug.obj?material=ceramic&up=y&scale=0.01``,
``ply:/captures/room.ply?up=y&scale=1.0``. The path runs to the last ``?``; values
are plain text (no percent-decoding). Each loader names the keys it accepts and
their meaning; an unknown key, a repeated key or a malformed pair is an error.
"""

from __future__ import annotations

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
