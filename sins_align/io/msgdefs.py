"""Message definitions (ROS 2 Jazzy, as rosbags generates them for a bag's connections)
and their RIHS01 hashes, for the topics replay --output writes: a writer gets them without
loading rosbags' typestore (about 0.4 s of a cold start). test_mcapwrite checks them against
the typestore.

A definition is the message's own fields, then each message type it uses, in the order
rosbags writes them, as ``MSG: <type>`` sections after a line of 80 ``=``."""

_RULE = "=" * 80 + "\n"

#: the fields of the types the definitions use
_FIELDS = {
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "geometry_msgs/Quaternion": "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "diagnostic_msgs/DiagnosticStatus": (
        "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\nbyte level\nstring name\n"
        "string message\nstring hardware_id\ndiagnostic_msgs/KeyValue[] values\n"),
    "diagnostic_msgs/KeyValue": "string key\nstring value\n",
}


def _definition(own: str, *used: str) -> str:
    return own + "".join(f"{_RULE}MSG: {t}\n{_FIELDS[t]}" for t in used)


_HEADER = ("std_msgs/Header", "builtin_interfaces/Time")

#: message type -> (definition text, RIHS01 hash)
DEFINITIONS = {
    "sensor_msgs/msg/Imu": (
        _definition("std_msgs/Header header\ngeometry_msgs/Quaternion orientation\n"
                    "float64[9] orientation_covariance\n"
                    "geometry_msgs/Vector3 angular_velocity\n"
                    "float64[9] angular_velocity_covariance\n"
                    "geometry_msgs/Vector3 linear_acceleration\n"
                    "float64[9] linear_acceleration_covariance\n",
                    *_HEADER, "geometry_msgs/Quaternion", "geometry_msgs/Vector3"),
        "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b"),
    "std_msgs/msg/Bool": (
        _definition("bool data\n"),
        "RIHS01_feb91e995ff9ebd09c0cb3d2aed18b11077585839fb5db80193b62d74528f6c9"),
    "geometry_msgs/msg/Vector3Stamped": (
        _definition("std_msgs/Header header\ngeometry_msgs/Vector3 vector\n",
                    *_HEADER, "geometry_msgs/Vector3"),
        "RIHS01_d4829622288cbb443886e7ea94ea5671a3b1be6bab4ad04224432a65f7d7887a"),
    "diagnostic_msgs/msg/DiagnosticArray": (
        _definition("std_msgs/Header header\ndiagnostic_msgs/DiagnosticStatus[] status\n",
                    *_HEADER, "diagnostic_msgs/DiagnosticStatus", "diagnostic_msgs/KeyValue"),
        "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e"),
}
