"""ros/thintact_msgs (the ROS 2 interface package) equals the schemas the MCAP writer declares,
and the writer's copies of standard ROS 2 types equal ROS 2's own, field by field (rosbags)."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from thintact_sdk.formats.mcap import schemas

PKG = Path(__file__).resolve().parents[2] / "ros" / "thintact_msgs"
SEPARATOR = "=" * 80
OWN = sorted(n for n in schemas.DEFINITIONS if n.startswith("thintact_msgs/"))


def _parts(definition: str) -> dict[str, str]:
    """``{type name: msg text}`` of a ros2msg schema (the main type, then each ``MSG:``)."""
    main, *nested = definition.split(SEPARATOR)
    out = {"": main}
    for block in nested:
        head, _, text = block.strip("\n").partition("\n")
        name = head.removeprefix("MSG: ").strip()
        pkg, typ = name.split("/")
        out[f"{pkg}/msg/{typ}"] = text
    return out


def test_the_package_holds_exactly_the_thintact_msgs_types():
    assert OWN == ["thintact_msgs/msg/Contact", "thintact_msgs/msg/Markers",
                   "thintact_msgs/msg/Slip"]
    files = sorted(p.name for p in (PKG / "msg").glob("*.msg"))
    assert files == sorted(n.rsplit("/", 1)[1] + ".msg" for n in OWN)
    cmake = (PKG / "CMakeLists.txt").read_text()
    assert "rosidl_generate_interfaces(${PROJECT_NAME}" in cmake
    assert sorted(re.findall(r'"(msg/\w+\.msg)"', cmake)) == sorted(f"msg/{f}" for f in files)
    root = ET.parse(PKG / "package.xml").getroot()
    assert root.findtext("name") == "thintact_msgs"
    assert root.findtext("member_of_group") == "rosidl_interface_packages"
    deps = {d.text for d in root.iter("depend")}
    used = {m.split("/")[0] for n in OWN for m in _parts(schemas.DEFINITIONS[n]) if m}
    assert used == {"std_msgs", "builtin_interfaces", "geometry_msgs"}
    assert {u for u in used if u != "builtin_interfaces"} <= deps  # std_msgs pulls it in
    assert {"rosidl_default_generators", "ament_cmake"} <= {
        d.text for d in root.iter("buildtool_depend")}


@pytest.mark.parametrize("name", OWN)
def test_msg_files_equal_the_writer_schemas_field_by_field(name):
    text = (PKG / "msg" / (name.rsplit("/", 1)[1] + ".msg")).read_text()
    from_file = get_types_from_msg(text, name)[name]
    from_writer = get_types_from_msg(_parts(schemas.DEFINITIONS[name])[""], name)[name]
    assert from_file == from_writer
    assert len(from_file[1]) >= 2 and from_file[1][0][0] == "header"


@pytest.mark.parametrize("name", sorted(schemas.DEFINITIONS))
def test_standard_types_in_the_schemas_equal_ros2(name):
    store = get_typestore(Stores.ROS2_HUMBLE)
    parts = _parts(schemas.DEFINITIONS[name])
    checked = 0
    for sub, text in parts.items():
        full = sub or name
        if full.startswith("thintact_msgs/"):
            continue
        ours = get_types_from_msg(text, full)[full]
        assert ours == store.fielddefs[full], full
        checked += 1
    assert checked >= 1  # every schema nests at least std_msgs/Header
