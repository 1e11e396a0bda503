"""Protobuf message classes for Waymo v1 frames.

The official ``waymo_open_dataset.dataset_pb2`` classes are used when that package imports;
otherwise the classes are built at import time from the project's own schema
(:mod:`idsplat_ns.data.waymo.proto.schema`). ``SCHEMA_SOURCE`` says which one is in use.
"""

from __future__ import annotations

import importlib
import importlib.util
import warnings

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from idsplat_ns.data.waymo.proto.schema import MESSAGES, PACKAGE, SCALAR_TYPES

_FDP = descriptor_pb2.FieldDescriptorProto
_SCALAR_ENUM = {
    "double": _FDP.TYPE_DOUBLE,
    "float": _FDP.TYPE_FLOAT,
    "int64": _FDP.TYPE_INT64,
    "int32": _FDP.TYPE_INT32,
    "bool": _FDP.TYPE_BOOL,
    "string": _FDP.TYPE_STRING,
    "bytes": _FDP.TYPE_BYTES,
}


def build_file_descriptor() -> descriptor_pb2.FileDescriptorProto:
    """The FileDescriptorProto of the project's schema."""
    fdp = descriptor_pb2.FileDescriptorProto(name="idsplat_waymo_subset.proto", package=PACKAGE, syntax="proto2")
    for name, fields in MESSAGES.items():
        msg = fdp.message_type.add(name=name)
        for field, number, ftype, label in fields:
            f = msg.field.add(name=field, number=number)
            f.label = _FDP.LABEL_REPEATED if label in ("repeated", "packed") else _FDP.LABEL_OPTIONAL
            if ftype in SCALAR_TYPES:
                f.type = _SCALAR_ENUM[ftype]
            else:
                f.type = _FDP.TYPE_MESSAGE
                f.type_name = f".{PACKAGE}.{ftype}"
            if label == "packed":
                f.options.packed = True
    return fdp


def _own_classes() -> dict[str, type]:
    pool = descriptor_pool.DescriptorPool()
    pool.Add(build_file_descriptor())
    # protobuf >= 4.21 makes classes with GetMessageClass and 5 removed GetPrototype; 3.20 has only that.
    message_class = getattr(message_factory, "GetMessageClass", None) or message_factory.MessageFactory(pool).GetPrototype
    return {name: message_class(pool.FindMessageTypeByName(f"{PACKAGE}.{name}")) for name in MESSAGES}


OWN = _own_classes()
"""The project's own message classes by name (always available; tests build frames with them)."""


def _official_classes() -> tuple[dict[str, type], str]:
    if importlib.util.find_spec("waymo_open_dataset") is None:
        return {}, "idsplat schema (waymo_open_dataset not installed)"
    try:
        dataset_pb2 = importlib.import_module("waymo_open_dataset.dataset_pb2")
    except Exception as err:  # an installed but broken package (e.g. protobuf version clash)
        warnings.warn(f"waymo_open_dataset is installed but its dataset_pb2 does not import ({err}); using idsplat's schema")
        return {}, f"idsplat schema (waymo_open_dataset failed to import: {type(err).__name__})"
    return {"Frame": dataset_pb2.Frame, "MatrixFloat": dataset_pb2.MatrixFloat, "MatrixInt32": dataset_pb2.MatrixInt32}, "waymo_open_dataset"


_OFFICIAL, SCHEMA_SOURCE = _official_classes()

Frame = _OFFICIAL.get("Frame", OWN["Frame"])
MatrixFloat = _OFFICIAL.get("MatrixFloat", OWN["MatrixFloat"])
MatrixInt32 = _OFFICIAL.get("MatrixInt32", OWN["MatrixInt32"])

__all__ = ["Frame", "MatrixFloat", "MatrixInt32", "OWN", "SCHEMA_SOURCE", "build_file_descriptor"]
