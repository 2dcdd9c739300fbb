"""ROS 2 message definitions (``ros2msg`` text, dependencies appended as ROS 2 tools do) and topics.

Standard messages are used wherever one fits, so Foxglove, evo and the ROS 2 tools read the logs;
tracks and correspondences, which have no standard message, use two small ``deepslam_msgs`` types.
"""

from __future__ import annotations

_SEPARATOR = "=" * 80

_DEFINITIONS = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Quaternion": "float64 x\nfloat64 y\nfloat64 z\nfloat64 w",
    "geometry_msgs/Pose": "Point position\nQuaternion orientation",
    "geometry_msgs/Transform": "Vector3 translation\nQuaternion rotation",
    "geometry_msgs/PoseStamped": "std_msgs/Header header\nPose pose",
    "geometry_msgs/PoseWithCovariance": "Pose pose\nfloat64[36] covariance",
    "geometry_msgs/PoseWithCovarianceStamped": "std_msgs/Header header\nPoseWithCovariance pose",
    "geometry_msgs/TransformStamped": "std_msgs/Header header\nstring child_frame_id\nTransform transform",
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms",
    "sensor_msgs/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data",
    "sensor_msgs/RegionOfInterest": "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify",
    "sensor_msgs/CameraInfo": (
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n"
        "float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n"
        "uint32 binning_y\nRegionOfInterest roi"
    ),
    "deepslam_msgs/Tracks": (
        "# tracked image points of one frame (pixels, top-left pixel centre at 0,0)\n"
        "std_msgs/Header header\nfloat32[] x\nfloat32[] y\nfloat32[] score\nint64[] id"
    ),
    "nav_msgs/Path": "std_msgs/Header header\ngeometry_msgs/PoseStamped[] poses",
    "geometry_msgs/PoseArray": "std_msgs/Header header\nPose[] poses",
    "sensor_msgs/PointField": (
        "uint8 INT8=1\nuint8 UINT8=2\nuint8 INT16=3\nuint8 UINT16=4\nuint8 INT32=5\nuint8 UINT32=6\nuint8 FLOAT32=7\n"
        "uint8 FLOAT64=8\nstring name\nuint32 offset\nuint8 datatype\nuint32 count"
    ),
    "sensor_msgs/PointCloud2": (
        "std_msgs/Header header\nuint32 height\nuint32 width\nPointField[] fields\nbool is_bigendian\n"
        "uint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense"
    ),
    "foxglove_msgs/Point2": "float64 x\nfloat64 y",
    "foxglove_msgs/Color": "float64 r\nfloat64 g\nfloat64 b\nfloat64 a",
    "foxglove_msgs/CircleAnnotation": (
        "builtin_interfaces/Time timestamp\nfoxglove_msgs/Point2 position\nfloat64 diameter\nfloat64 thickness\n"
        "foxglove_msgs/Color fill_color\nfoxglove_msgs/Color outline_color"
    ),
    "foxglove_msgs/PointsAnnotation": (
        "builtin_interfaces/Time timestamp\nuint8 UNKNOWN=0\nuint8 POINTS=1\nuint8 LINE_LOOP=2\nuint8 LINE_STRIP=3\n"
        "uint8 LINE_LIST=4\nuint8 type\nfoxglove_msgs/Point2[] points\nfoxglove_msgs/Color outline_color\n"
        "foxglove_msgs/Color[] outline_colors\nfoxglove_msgs/Color fill_color\nfloat64 thickness"
    ),
    "foxglove_msgs/TextAnnotation": (
        "builtin_interfaces/Time timestamp\nfoxglove_msgs/Point2 position\nstring text\nfloat64 font_size\n"
        "foxglove_msgs/Color text_color\nfoxglove_msgs/Color background_color"
    ),
    "foxglove_msgs/ImageAnnotations": (
        "foxglove_msgs/CircleAnnotation[] circles\nfoxglove_msgs/PointsAnnotation[] points\n"
        "foxglove_msgs/TextAnnotation[] texts"
    ),
    "deepslam_msgs/FrameDiagnostics": (
        "# how the front-end and odometry did on one frame; NaN where a figure needs truth the run lacks\n"
        "std_msgs/Header header\nuint32 tracks\nuint32 inliers\nbool lost\nstring reason\n"
        "float64 correspondence_error_px\nfloat64 position_error_m\nbool keyframe\nfloat64 pair_error_px\n"
        "uint32 landmarks\nstring phase\nstring keyframe_reason"
    ),
    "deepslam_msgs/Correspondences": (
        "# matches between the reference keyframe's tracks and this frame's, and the relative pose from them\n"
        "std_msgs/Header header\nbuiltin_interfaces/Time reference_stamp\nuint32[] reference_index\n"
        "uint32[] current_index\nstring model\nuint32 inliers\nfloat64[16] t_ref_cur"
    ),
}

_DEPENDENCIES = {
    "std_msgs/Header": ["builtin_interfaces/Time"],
    "geometry_msgs/Pose": ["geometry_msgs/Point", "geometry_msgs/Quaternion"],
    "geometry_msgs/Transform": ["geometry_msgs/Vector3", "geometry_msgs/Quaternion"],
    "geometry_msgs/PoseStamped": ["std_msgs/Header", "geometry_msgs/Pose"],
    "geometry_msgs/PoseWithCovariance": ["geometry_msgs/Pose"],
    "geometry_msgs/PoseWithCovarianceStamped": ["std_msgs/Header", "geometry_msgs/PoseWithCovariance"],
    "geometry_msgs/TransformStamped": ["std_msgs/Header", "geometry_msgs/Transform"],
    "tf2_msgs/TFMessage": ["geometry_msgs/TransformStamped"],
    "sensor_msgs/CompressedImage": ["std_msgs/Header"],
    "sensor_msgs/CameraInfo": ["std_msgs/Header", "sensor_msgs/RegionOfInterest"],
    "deepslam_msgs/Tracks": ["std_msgs/Header"],
    "deepslam_msgs/Correspondences": ["std_msgs/Header", "builtin_interfaces/Time"],
    "deepslam_msgs/FrameDiagnostics": ["std_msgs/Header"],
    "nav_msgs/Path": ["std_msgs/Header", "geometry_msgs/PoseStamped"],
    "geometry_msgs/PoseArray": ["std_msgs/Header", "geometry_msgs/Pose"],
    "sensor_msgs/PointCloud2": ["std_msgs/Header", "sensor_msgs/PointField"],
    "foxglove_msgs/CircleAnnotation": ["builtin_interfaces/Time", "foxglove_msgs/Point2", "foxglove_msgs/Color"],
    "foxglove_msgs/PointsAnnotation": ["builtin_interfaces/Time", "foxglove_msgs/Point2", "foxglove_msgs/Color"],
    "foxglove_msgs/TextAnnotation": ["builtin_interfaces/Time", "foxglove_msgs/Point2", "foxglove_msgs/Color"],
    "foxglove_msgs/ImageAnnotations": [
        "foxglove_msgs/CircleAnnotation",
        "foxglove_msgs/PointsAnnotation",
        "foxglove_msgs/TextAnnotation",
    ],
}


def _closure(name: str) -> list[str]:
    seen: list[str] = []

    def visit(n: str) -> None:
        for dep in _DEPENDENCIES.get(n, []):
            if dep not in seen:
                seen.append(dep)
                visit(dep)

    visit(name)
    return seen


def msgdef(name: str) -> str:
    """The full ``ros2msg`` text of a message type ("pkg/Type"), its dependencies appended."""
    parts = [_DEFINITIONS[name]] + [f"{_SEPARATOR}\nMSG: {dep}\n{_DEFINITIONS[dep]}" for dep in _closure(name)]
    return "\n".join(parts)


def ros2_name(name: str) -> str:
    """ "pkg/Type" -> "pkg/msg/Type", the schema name ROS 2 tools expect."""
    package, type_name = name.split("/")
    return f"{package}/msg/{type_name}"


TOPICS = {
    "/camera/image": "sensor_msgs/CompressedImage",
    "/camera/camera_info": "sensor_msgs/CameraInfo",
    "/groundtruth/pose": "geometry_msgs/PoseStamped",
    "/estimate/pose": "geometry_msgs/PoseStamped",
    "/estimate/pose_covariance": "geometry_msgs/PoseWithCovarianceStamped",
    "/tf": "tf2_msgs/TFMessage",
    "/frontend/tracks": "deepslam_msgs/Tracks",
    "/frontend/correspondences": "deepslam_msgs/Correspondences",
    "/diagnostics/frame": "deepslam_msgs/FrameDiagnostics",
    "/camera/annotations": "foxglove_msgs/ImageAnnotations",
    "/estimate/path": "nav_msgs/Path",
    "/groundtruth/path": "nav_msgs/Path",
    "/map/landmarks": "sensor_msgs/PointCloud2",
    "/map/keyframes": "geometry_msgs/PoseArray",
}
"""Every topic a run writes, with its message type. Ground truth is absent in logs of real data."""

FRAME_TOPICS = ("/camera/image", "/camera/camera_info")
"""The topics that make a frame replayable."""

WORLD_FRAME = "world"
CAMERA_FRAME = "camera"  # the optical frame (x right, y down, z ahead)
GROUNDTRUTH_FRAME = "camera_groundtruth"


SUMMARY_RECORD = "deepslam_summary"  # the metadata record of a run's figures, written when it ends
METADATA_CHECKSUM = "crc32"  # the metadata entry that protects the others (MCAP leaves metadata records unchecked)


def metadata_checksum(entries: dict[str, str]) -> str:
    """The CRC-32 (hex) of a metadata record's entries other than the checksum itself, in key order."""
    import json
    import zlib

    payload = json.dumps({k: v for k, v in sorted(entries.items()) if k != METADATA_CHECKSUM}, sort_keys=True)
    return f"{zlib.crc32(payload.encode()):08x}"
