"""Topics and ROS 2 message definitions of a ThinTact MCAP log (see docs/logging.md).

Every schema is stored in the file as ``ros2msg`` text (the message followed by each
nested definition after a ``===`` separator, as ``ros2 bag`` writes it), so Foxglove,
``ros2 bag`` and the ``mcap`` readers decode the ``thintact_msgs`` types without a ROS
installation or a compiled package.
"""

from __future__ import annotations

from dataclasses import dataclass

LOG_FORMAT = "thintact-mcap/1"
"""Value of the ``format`` key of the ``thintact`` metadata record."""

_SEPARATOR = "=" * 80

_TIME = """\
int32 sec
uint32 nanosec"""

_HEADER = """\
builtin_interfaces/Time stamp
string frame_id"""

_VECTOR3 = """\
float64 x
float64 y
float64 z"""

_IMAGE = """\
std_msgs/Header header
uint32 height
uint32 width
string encoding
uint8 is_bigendian
uint32 step
uint8[] data"""

_WRENCH_STAMPED = """\
std_msgs/Header header
geometry_msgs/Wrench wrench"""

_WRENCH = """\
geometry_msgs/Vector3 force
geometry_msgs/Vector3 torque"""

_MARKERS = """\
# Marker centres and their displacement from the no-contact reference, membrane plane, mm.
std_msgs/Header header
uint32 count                 # K markers
float32[] positions_mm       # 2K values x0, y0, x1, y1, ...; NaN where a marker is lost
float32[] displacements_mm   # 2K values dx0, dy0, dx1, dy1, ..."""

_CONTACT = """\
# Contact interpretation of one tactile frame.
std_msgs/Header header
uint64 camera_frame_id       # the camera's frame counter (gaps: dropped frames)
bool contact                 # a contact region (deeper than the profile's contact threshold, concave) of >= 0.1 mm2
float32 contact_area_mm2
float32 max_depth_mm         # deepest indentation, mm
float32 shear_direction_rad  # atan2 of the mean marker displacement; NaN without shear
geometry_msgs/Vector3 mean_displacement_mm   # mean marker displacement (x, y, 0), mm
float32 latency_ms           # raw frame -> tactile frame processing time; NaN if unknown"""

_SLIP = """\
# Partial-slip signal of one tactile frame.
std_msgs/Header header
float32 slip_ratio           # fraction of the loaded contact that slips, 0..1
bool slipping                # slip_ratio >= 0.15: the contact slips (incipient slip)"""


def _definition(main: str, *nested: tuple[str, str]) -> str:
    parts = [main]
    for name, text in nested:
        parts.append(f"{_SEPARATOR}\nMSG: {name}\n{text}")
    return "\n".join(parts) + "\n"


_HEADER_DEPS = (("std_msgs/Header", _HEADER), ("builtin_interfaces/Time", _TIME))

IMAGE = "sensor_msgs/msg/Image"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
MARKERS = "thintact_msgs/msg/Markers"
CONTACT = "thintact_msgs/msg/Contact"
SLIP = "thintact_msgs/msg/Slip"

DEFINITIONS: dict[str, str] = {
    IMAGE: _definition(_IMAGE, *_HEADER_DEPS),
    WRENCH_STAMPED: _definition(
        _WRENCH_STAMPED, *_HEADER_DEPS, ("geometry_msgs/Wrench", _WRENCH),
        ("geometry_msgs/Vector3", _VECTOR3),
    ),
    MARKERS: _definition(_MARKERS, *_HEADER_DEPS),
    CONTACT: _definition(_CONTACT, *_HEADER_DEPS, ("geometry_msgs/Vector3", _VECTOR3)),
    SLIP: _definition(_SLIP, *_HEADER_DEPS),
}
"""ROS 2 ``.msg`` text of every message type a log uses, with its nested definitions."""


@dataclass(frozen=True)
class Topic:
    """One channel of a log: its topic name, message type and what it carries."""

    name: str
    schema: str
    what: str


RAW = Topic("/thintact/raw", IMAGE,
            "the camera frame (Bayer mosaic: bayer_rggb16 etc., or mono/rgb); 16-bit data "
            "MSB-aligned, the shift in the thintact.raw metadata")
RAW_PREVIEW = Topic("/thintact/raw_preview", IMAGE,
                    "rgb8 preview of a raw frame viewers cannot decode (bayer_*16, rgb16): "
                    "Bayer binned to half resolution")
IMAGE_TOPIC = Topic("/thintact/image", IMAGE,
                    "reconstructed membrane image (rgb8, or 32FC3 display units)")
DEPTH = Topic("/thintact/depth", IMAGE, "indentation depth, 32FC1, millimetres")
MARKERS_TOPIC = Topic("/thintact/markers", MARKERS, "marker positions and displacements, mm")
CONTACT_TOPIC = Topic("/thintact/contact", CONTACT, "contact flag, area, depth, shear")
FORCE = Topic("/thintact/force", WRENCH_STAMPED,
              "estimated contact force [Fx, Fy, Fz] in newtons (torque 0: not estimated)")
SLIP_TOPIC = Topic("/thintact/slip", SLIP,
                   "slip ratio and slipping flag, when the frame has a slip ratio")

TOPICS: tuple[Topic, ...] = (RAW, RAW_PREVIEW, IMAGE_TOPIC, DEPTH, MARKERS_TOPIC, CONTACT_TOPIC, FORCE,
                             SLIP_TOPIC)
"""Every topic a ThinTact log may hold (a topic with no message has no channel)."""
