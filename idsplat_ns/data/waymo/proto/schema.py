"""The project's own schema for the subset of Waymo's ``Frame`` message that the parser reads.

Field numbers and wire types are facts of the published format (``dataset.proto``,
``label.proto``); message and field names follow it so that the official generated classes, when
installed, can be used interchangeably. Enums are declared as ``int32`` (the same varint on the
wire), nested messages are flattened to top-level names (names are not on the wire), and fields the
parser does not use are left out: protobuf skips unknown fields when parsing.
"""

from __future__ import annotations

PACKAGE = "idsplat.waymo_subset"

# message name -> [(field name, number, type, label)], type is a scalar name or a message name;
# label is "optional", "repeated" or "packed" (repeated, packed encoding).
MESSAGES: dict[str, list[tuple[str, int, str, str]]] = {
    "MatrixShape": [("dims", 1, "int32", "repeated")],
    "MatrixFloat": [("data", 1, "float", "packed"), ("shape", 2, "MatrixShape", "optional")],
    "MatrixInt32": [("data", 1, "int32", "packed"), ("shape", 2, "MatrixShape", "optional")],
    "Transform": [("transform", 1, "double", "repeated")],
    "Velocity": [
        ("v_x", 1, "float", "optional"), ("v_y", 2, "float", "optional"), ("v_z", 3, "float", "optional"),
        ("w_x", 4, "double", "optional"), ("w_y", 5, "double", "optional"), ("w_z", 6, "double", "optional"),
    ],
    "CameraCalibration": [
        ("name", 1, "int32", "optional"),  # CameraName.Name
        ("intrinsic", 2, "double", "repeated"),  # f_u, f_v, c_u, c_v, k1, k2, p1, p2, k3
        ("extrinsic", 3, "Transform", "optional"),  # camera (x forward, y left, z up) to vehicle
        ("width", 4, "int32", "optional"),
        ("height", 5, "int32", "optional"),
        ("rolling_shutter_direction", 6, "int32", "optional"),
    ],
    "LaserCalibration": [
        ("name", 1, "int32", "optional"),  # LaserName.Name
        ("beam_inclinations", 2, "double", "repeated"),  # non-uniform rows, bottom to top (radians)
        ("beam_inclination_min", 3, "double", "optional"),
        ("beam_inclination_max", 4, "double", "optional"),
        ("extrinsic", 5, "Transform", "optional"),  # lidar to vehicle
    ],
    "ContextStats": [
        ("time_of_day", 2, "string", "optional"),
        ("location", 3, "string", "optional"),
        ("weather", 4, "string", "optional"),
    ],
    "Context": [
        ("name", 1, "string", "optional"),
        ("camera_calibrations", 2, "CameraCalibration", "repeated"),
        ("laser_calibrations", 3, "LaserCalibration", "repeated"),
        ("stats", 4, "ContextStats", "optional"),
    ],
    "RangeImage": [
        ("range_image_compressed", 2, "bytes", "optional"),  # zlib(MatrixFloat [H, W, 4])
        ("camera_projection_compressed", 3, "bytes", "optional"),  # zlib(MatrixInt32 [H, W, 6])
        ("range_image_pose_compressed", 4, "bytes", "optional"),  # zlib(MatrixFloat [H, W, 6]), TOP return 1
        ("range_image_flow_compressed", 5, "bytes", "optional"),
        ("segmentation_label_compressed", 6, "bytes", "optional"),
    ],
    "InstanceIDToGlobalIDMapping": [
        ("local_instance_id", 1, "int32", "optional"),
        ("global_instance_id", 2, "int32", "optional"),
        ("is_tracked", 3, "bool", "optional"),
    ],
    "CameraSegmentationLabel": [
        ("panoptic_label_divisor", 1, "int32", "optional"),
        ("panoptic_label", 2, "bytes", "optional"),  # uint16 PNG: semantic * divisor + instance
        ("instance_id_to_global_id_mapping", 3, "InstanceIDToGlobalIDMapping", "repeated"),
        ("sequence_id", 4, "string", "optional"),
        ("num_cameras_covered", 5, "bytes", "optional"),
    ],
    "CameraImage": [
        ("name", 1, "int32", "optional"),
        ("image", 2, "bytes", "optional"),  # JPEG
        ("pose", 3, "Transform", "optional"),  # vehicle to world at pose_timestamp
        ("velocity", 4, "Velocity", "optional"),
        ("pose_timestamp", 5, "double", "optional"),  # unix seconds
        ("shutter", 6, "double", "optional"),
        ("camera_trigger_time", 7, "double", "optional"),
        ("camera_readout_done_time", 8, "double", "optional"),
        ("camera_segmentation_label", 10, "CameraSegmentationLabel", "optional"),
    ],
    "LabelBox": [
        ("center_x", 1, "double", "optional"), ("center_y", 2, "double", "optional"),
        ("center_z", 3, "double", "optional"), ("width", 4, "double", "optional"),
        ("length", 5, "double", "optional"), ("height", 6, "double", "optional"),
        ("heading", 7, "double", "optional"),
    ],
    "LabelMetadata": [
        ("speed_x", 1, "double", "optional"), ("speed_y", 2, "double", "optional"),
        ("accel_x", 3, "double", "optional"), ("accel_y", 4, "double", "optional"),
        ("speed_z", 5, "double", "optional"), ("accel_z", 6, "double", "optional"),
    ],
    "Label": [
        ("box", 1, "LabelBox", "optional"),
        ("metadata", 2, "LabelMetadata", "optional"),
        ("type", 3, "int32", "optional"),  # 1 vehicle, 2 pedestrian, 3 sign, 4 cyclist
        ("id", 4, "string", "optional"),
        ("detection_difficulty_level", 5, "int32", "optional"),
        ("tracking_difficulty_level", 6, "int32", "optional"),
        ("num_lidar_points_in_box", 7, "int32", "optional"),
        ("most_visible_camera_name", 11, "string", "optional"),
        ("camera_synced_box", 12, "LabelBox", "optional"),
        ("num_top_lidar_points_in_box", 13, "int32", "optional"),
    ],
    "CameraLabels": [("name", 1, "int32", "optional"), ("labels", 2, "Label", "repeated")],
    "Laser": [
        ("name", 1, "int32", "optional"),
        ("ri_return1", 2, "RangeImage", "optional"),
        ("ri_return2", 3, "RangeImage", "optional"),
    ],
    "Frame": [
        ("context", 1, "Context", "optional"),
        ("timestamp_micros", 2, "int64", "optional"),  # start of the TOP lidar sweep
        ("pose", 3, "Transform", "optional"),  # vehicle to world, ~ middle of the sweep
        ("images", 4, "CameraImage", "repeated"),
        ("lasers", 5, "Laser", "repeated"),
        ("laser_labels", 6, "Label", "repeated"),  # in the frame's vehicle frame
        ("camera_labels", 8, "CameraLabels", "repeated"),
        ("projected_lidar_labels", 9, "CameraLabels", "repeated"),
    ],
}

SCALAR_TYPES = ("double", "float", "int64", "int32", "bool", "string", "bytes")


def to_proto_text() -> str:
    """The schema as ``.proto`` source (the shipped ``frame_subset.proto`` is this text)."""
    lines = [
        "// Generated from idsplat_ns/data/waymo/proto/schema.py (the source of truth); do not edit.",
        "// The subset of the Waymo Open Dataset v1 Frame that idsplat_ns reads.",
        'syntax = "proto2";',
        "",
        f"package {PACKAGE};",
        "",
    ]
    for name, fields in MESSAGES.items():
        lines.append(f"message {name} {{")
        for field, number, ftype, label in fields:
            option = " [packed = true]" if label == "packed" else ""
            plabel = "repeated" if label in ("repeated", "packed") else "optional"
            lines.append(f"  {plabel} {ftype} {field} = {number}{option};")
        lines.append("}")
        lines.append("")
    return "\n".join(lines)
