"""JSON schemas of the messages an aia run log holds.

Foxglove recognises its built-in message types by schema *name* (``foxglove.SceneUpdate`` ...); the schema
bodies written here describe the fields aia emits, in the form of Foxglove's published JSON schemas
(times as ``{sec, nsec}`` objects titled ``time``/``duration``, enums as integers, nested types titled
with their Foxglove names), so that Foxglove's message-path completion and plots see typed fields.
The two aia types (``aia.Scalar``, ``aia.Histogram``) are plain JSON objects that Foxglove plots directly.
"""

from __future__ import annotations

import json
from typing import Any

SCHEMA_ENCODING = "jsonschema"
MESSAGE_ENCODING = "json"

SCENE_UPDATE = "foxglove.SceneUpdate"
FRAME_TRANSFORM = "foxglove.FrameTransform"
LOG = "foxglove.Log"
COMPRESSED_IMAGE = "foxglove.CompressedImage"
POINT_CLOUD = "foxglove.PointCloud"
SCALAR = "aia.Scalar"
HISTOGRAM = "aia.Histogram"

NUMBER: dict[str, Any] = {"type": "number"}
INTEGER: dict[str, Any] = {"type": "integer"}
STRING: dict[str, Any] = {"type": "string"}
BOOLEAN: dict[str, Any] = {"type": "boolean"}
_BASE64: dict[str, Any] = {"type": "string", "contentEncoding": "base64"}  # bytes, as JSON carries them


def _object(title: str | None = None, **properties: dict[str, Any]) -> dict[str, Any]:
    """An object schema whose every listed property is required."""
    schema: dict[str, Any] = {"type": "object", "properties": properties, "required": list(properties)}
    if title:
        schema = {"title": title, **schema}
    return schema


def _array(items: dict[str, Any]) -> dict[str, Any]:
    return {"type": "array", "items": items}


def _enum(title: str, *names: str) -> dict[str, Any]:
    return {"title": title, "oneOf": [{"title": name, "const": i} for i, name in enumerate(names)]}


_TIME = {"type": "object", "title": "time", "properties": {"sec": INTEGER, "nsec": INTEGER}}
_DURATION = {"type": "object", "title": "duration", "properties": {"sec": INTEGER, "nsec": INTEGER}}
_VECTOR3 = _object("foxglove.Vector3", x=NUMBER, y=NUMBER, z=NUMBER)
_POINT3 = _object("foxglove.Point3", x=NUMBER, y=NUMBER, z=NUMBER)
_QUATERNION = _object("foxglove.Quaternion", x=NUMBER, y=NUMBER, z=NUMBER, w=NUMBER)
_POSE = _object("foxglove.Pose", position=_VECTOR3, orientation=_QUATERNION)
_COLOR = _object("foxglove.Color", r=NUMBER, g=NUMBER, b=NUMBER, a=NUMBER)
_KEY_VALUE = _object("foxglove.KeyValuePair", key=STRING, value=STRING)
_SHAPE = {"pose": _POSE, "size": _VECTOR3, "color": _COLOR}
_ARROW = _object("foxglove.ArrowPrimitive", pose=_POSE, shaft_length=NUMBER, shaft_diameter=NUMBER,
                 head_length=NUMBER, head_diameter=NUMBER, color=_COLOR)
_LINE = _object("foxglove.LinePrimitive", type=_enum("foxglove.LineType", "LINE_STRIP", "LINE_LOOP", "LINE_LIST"),
                pose=_POSE, thickness=NUMBER, scale_invariant=BOOLEAN, points=_array(_POINT3), color=_COLOR,
                colors=_array(_COLOR), indices=_array(INTEGER))
_UNUSED_PRIMITIVES = ("cylinders", "triangles", "texts", "models")  # aia draws none of these
_ENTITY = _object(
    "foxglove.SceneEntity", timestamp=_TIME, frame_id=STRING, id=STRING, lifetime=_DURATION,
    frame_locked=BOOLEAN, metadata=_array(_KEY_VALUE), arrows=_array(_ARROW),
    cubes=_array(_object("foxglove.CubePrimitive", **_SHAPE)),
    spheres=_array(_object("foxglove.SpherePrimitive", **_SHAPE)), lines=_array(_LINE),
    **{name: _array({"type": "object"}) for name in _UNUSED_PRIMITIVES},
)
_DELETION = _object("foxglove.SceneEntityDeletion", timestamp=_TIME,
                    type=_enum("foxglove.SceneEntityDeletionType", "MATCHING_ID", "ALL"), id=STRING)

SCHEMAS: dict[str, dict[str, Any]] = {
    SCENE_UPDATE: _object(SCENE_UPDATE, deletions=_array(_DELETION), entities=_array(_ENTITY)),
    FRAME_TRANSFORM: _object(FRAME_TRANSFORM, timestamp=_TIME, parent_frame_id=STRING, child_frame_id=STRING,
                             translation=_VECTOR3, rotation=_QUATERNION),
    LOG: _object(LOG, timestamp=_TIME,
                 level=_enum("foxglove.LogLevel", "UNKNOWN", "DEBUG", "INFO", "WARNING", "ERROR", "FATAL"),
                 message=STRING, name=STRING, file=STRING, line=INTEGER),
    COMPRESSED_IMAGE: _object(COMPRESSED_IMAGE, timestamp=_TIME, frame_id=STRING,
                              data=_BASE64, format=STRING),
    POINT_CLOUD: _object(POINT_CLOUD, timestamp=_TIME, frame_id=STRING, pose=_POSE, point_stride=INTEGER,
                         fields=_array(_object("foxglove.PackedElementField", name=STRING, offset=INTEGER,
                                               type=_enum("foxglove.NumericType", "UNKNOWN", "UINT8", "INT8",
                                                          "UINT16", "INT16", "UINT32", "INT32", "FLOAT32",
                                                          "FLOAT64"))),
                         data=_BASE64),
    SCALAR: _object(SCALAR, frame=INTEGER, value=NUMBER),
    HISTOGRAM: _object(HISTOGRAM, frame=INTEGER, edges=_array(NUMBER), counts=_array(NUMBER)),
}

LOG_LEVELS = {"debug": 1, "info": 2, "warning": 3, "error": 4, "fatal": 5}


def schema_bytes(name: str) -> bytes:
    """The JSON schema of message type ``name`` as MCAP schema data."""
    if name not in SCHEMAS:
        raise ValueError(f"unknown message type {name!r}: expected one of {sorted(SCHEMAS)}")
    return json.dumps(SCHEMAS[name], separators=(",", ":")).encode()
