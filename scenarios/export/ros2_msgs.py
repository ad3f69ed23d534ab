"""The ROS 2 message definitions and QoS profiles an MCAP bag of a run declares.

An MCAP file in the ``ros2`` profile names each message type and carries its definition as
``ros2msg`` text: the type's own ``.msg`` fields, then every type it uses, each once, after a
line of 80 ``=`` and ``MSG: pkg/Type`` (the layout rosbag2 writes, depth first in field order).
The fields below are those of ROS 2 Humble (Jazzy's are the same on the wire: it only adds
the constant ``Marker.ARROW_STRIP``), without their comments. ``msgdef`` assembles the text.

Each channel also says what QoS its publisher offered (``offered_qos_profiles``, YAML, in the
integer form rosbag2 has written since Humble and still reads): ``/tf_static`` and ``/cones``
are *transient local*, as tf2's static broadcaster offers, so that ``ros2 bag play`` latches
them for late subscribers; the other topics are volatile.
"""

from __future__ import annotations

import re

__all__ = ["MSG_FIELDS", "QOS_LATCHED", "QOS_VOLATILE", "msgdef"]

MSG_FIELDS: dict[str, str] = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "builtin_interfaces/Duration": "int32 sec\nuint32 nanosec\n",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "std_msgs/ColorRGBA": "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n",
    "geometry_msgs/Pose": "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
    "geometry_msgs/Transform": (
        "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n"
    ),
    "geometry_msgs/TransformStamped": (
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n"
    ),
    "geometry_msgs/PoseStamped": "std_msgs/Header header\ngeometry_msgs/Pose pose\n",
    "geometry_msgs/PointStamped": "std_msgs/Header header\ngeometry_msgs/Point point\n",
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
    "sensor_msgs/Image": (
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n"
        "uint8 is_bigendian\nuint32 step\nuint8[] data\n"
    ),
    "sensor_msgs/RegionOfInterest": (
        "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n"
    ),
    "sensor_msgs/CameraInfo": (
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n"
        "float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n"
        "uint32 binning_y\nsensor_msgs/RegionOfInterest roi\n"
    ),
    "sensor_msgs/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data\n",
    "sensor_msgs/Imu": (
        "std_msgs/Header header\ngeometry_msgs/Quaternion orientation\n"
        "float64[9] orientation_covariance\ngeometry_msgs/Vector3 angular_velocity\n"
        "float64[9] angular_velocity_covariance\ngeometry_msgs/Vector3 linear_acceleration\n"
        "float64[9] linear_acceleration_covariance\n"
    ),
    "visualization_msgs/UVCoordinate": "float32 u\nfloat32 v\n",
    "visualization_msgs/MeshFile": "string filename\nuint8[] data\n",
    "visualization_msgs/Marker": (
        "int32 ARROW=0\nint32 CUBE=1\nint32 SPHERE=2\nint32 CYLINDER=3\nint32 LINE_STRIP=4\n"
        "int32 LINE_LIST=5\nint32 CUBE_LIST=6\nint32 SPHERE_LIST=7\nint32 POINTS=8\n"
        "int32 TEXT_VIEW_FACING=9\nint32 MESH_RESOURCE=10\nint32 TRIANGLE_LIST=11\n"
        "int32 ADD=0\nint32 MODIFY=0\nint32 DELETE=2\nint32 DELETEALL=3\n"
        "std_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\n"
        "geometry_msgs/Pose pose\ngeometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\n"
        "builtin_interfaces/Duration lifetime\nbool frame_locked\n"
        "geometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] colors\n"
        "string texture_resource\nsensor_msgs/CompressedImage texture\n"
        "visualization_msgs/UVCoordinate[] uv_coordinates\nstring text\n"
        "string mesh_resource\nvisualization_msgs/MeshFile mesh_file\n"
        "bool mesh_use_embedded_materials\n"
    ),
    "visualization_msgs/MarkerArray": "visualization_msgs/Marker[] markers\n",
}
"""Each type's own fields (and constants), one ``.msg`` line each, keyed ``pkg/Type``."""

_SEPARATOR = "=" * 80 + "\n"
_NESTED = re.compile(r"^(\w+/\w+)(?:\[\d*\])? \w+$")


def _short(type_name: str) -> str:
    """``pkg/msg/Type`` or ``pkg/Type`` as ``pkg/Type``."""
    parts = type_name.split("/")
    if len(parts) == 3 and parts[1] == "msg":
        return f"{parts[0]}/{parts[2]}"
    return type_name


def msgdef(type_name: str) -> str:
    """The ``ros2msg`` text of ``type_name`` (``pkg/msg/Type``): its fields, then each type it
    uses, once, depth first in field order.

    Raises
    ------
    ValueError
        If the type or one it uses is not in ``MSG_FIELDS``.
    """
    top = _short(type_name)
    seen: list[str] = []

    def visit(name: str) -> None:
        if name not in MSG_FIELDS:
            raise ValueError(f"no ROS 2 message definition for {name!r} (in {type_name!r})")
        seen.append(name)
        for line in MSG_FIELDS[name].splitlines():
            m = _NESTED.match(line)
            if m and m.group(1) not in seen:
                visit(m.group(1))

    visit(top)
    sections = [MSG_FIELDS[top]]
    sections += [f"{_SEPARATOR}MSG: {name}\n{MSG_FIELDS[name]}" for name in seen[1:]]
    return "".join(sections)


def _qos_yaml(durability: int, depth: int) -> str:
    """One offered QoS profile as rosbag2 stores it: keep-last ``depth``, reliable, the given
    durability (1 transient local, 2 volatile: rmw's enumerations), automatic liveliness,
    default (zero: unspecified) deadline, lifespan and lease."""
    zero = "\n    sec: 0\n    nsec: 0"
    return (
        f"- history: 1\n  depth: {depth}\n  reliability: 1\n  durability: {durability}\n"
        f"  deadline:{zero}\n  lifespan:{zero}\n  liveliness: 1\n"
        f"  liveliness_lease_duration:{zero}\n  avoid_ros_namespace_conventions: false"
    )


QOS_LATCHED = _qos_yaml(durability=1, depth=1)
"""Transient local, depth 1: what ``tf2_ros.StaticTransformBroadcaster`` offers."""

QOS_VOLATILE = _qos_yaml(durability=2, depth=10)
"""Volatile, depth 10: an ordinary sensor or pose publisher."""
