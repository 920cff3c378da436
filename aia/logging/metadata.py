"""Conventions of a run log's metadata that readers share with the writer, importable without torch (so that
``aia-log`` starts in a fraction of a second, and the apps' configs name the compressions): the early-end status
record's name, the config's flattening, the log's file name and its chunks' compressions."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import yaml
from mcap.writer import CompressionType

RUN_LOG = "run.mcap"  # a run's log in its folder (MCAPLogger's file_name by default)
COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
STATUS_METADATA = "status"  # written only by a run that ended early: {"status": "failed" | "stopped", "reason"}


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """``{"a": {"b": 1}}`` -> ``{"a.b": "1"}`` (lists and scalars become their YAML flow text)."""
    flat: dict[str, str] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and value:
            flat.update(flatten(value, f"{name}."))
        else:
            flat[name] = yaml.safe_dump(value, default_flow_style=True).strip().removesuffix("\n...").strip()
    return flat
