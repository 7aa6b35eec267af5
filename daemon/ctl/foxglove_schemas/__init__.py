"""Foxglove's published JSON schemas of the well-known messages a recording uses, vendored as data.

Each ``*.json`` here is byte for byte ``schemas/jsonschema/<Name>.json`` of Foxglove's SDK
(https://github.com/foxglove/foxglove-sdk, commit ca8a1ced73b2737d03e2e3f282b57359a1a4cb72,
2026-08-17; MIT licence, Copyright (c) Foxglove Technologies Inc). ``ritactl record`` writes them
as the schemas of its JSON Foxglove channels (Foxglove knows the messages by the schema's name,
``foxglove.PoseInFrame`` …), and the tests validate every such message against them. The images
go in their ROS 2 form (``foxglove_msgs/msg/RawImage``, ``CompressedImage``: the same fields),
checked against RawImage.json and CompressedImage.json after decoding.
"""
from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

FOLDER = Path(__file__).parent


@cache
def schema_bytes(name: str) -> bytes:
    """The published schema of ``foxglove.<name>`` as Foxglove ships it (``name``: ``PoseInFrame``)."""
    return (FOLDER / f"{name}.json").read_bytes()


def schema(name: str) -> dict[str, Any]:
    """The same, parsed."""
    parsed: dict[str, Any] = json.loads(schema_bytes(name))
    return parsed
