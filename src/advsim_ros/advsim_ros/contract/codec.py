"""Messages as CDR bytes: one rosbags typestore (ROS 2 Jazzy + advsim_msgs + Autoware), stamps and headers.

The graph's nodes publish and subscribe raw CDR (rclpy's ``publish(bytes)`` and ``raw=True``
subscriptions) built here, and the bag layer writes the same bytes, so a recorded message is
exactly what was on the topic. advsim_msgs types, and the Autoware messages the Autoware adapters
speak, are registered from their .msg files (msg_defs/, or an installed package's share folder).
"""

from __future__ import annotations

import functools
import os
import struct
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from advsim_ros.contract import names
from advsim_ros.core.types import ScenarioError

if TYPE_CHECKING:
    from rosbags.interfaces.typing import Typesdict

# A message object: a rosbags typestore message or an rclpy one. Untyped at the DDS/rosbags boundary:
# rosbags builds its message classes at run time from .msg definitions (no static type names them) and
# the graph's code reads rclpy's and rosbags' objects alike by field name. The builders and parsers of
# contract/ turn them into typed records; nothing else of the package should need this alias.
Msg: TypeAlias = Any

MSG_DIR_ENV = "ADVSIM_MSG_DIR"  # folder of advsim_msgs/msg/*.msg, overriding the search below
ADVSIM_MSGS = "advsim_msgs"
# The Autoware messages of msg_defs/: same names and fields as Autoware's own packages, so a full
# Autoware install's share folder serves as well (only these files of it are read).
AUTOWARE_MESSAGES: dict[str, tuple[str, ...]] = {
    "autoware_planning_msgs": ("Trajectory", "TrajectoryPoint"),
    "autoware_perception_msgs": (
        "DetectedObject",
        "DetectedObjectKinematics",
        "DetectedObjects",
        "ObjectClassification",
        "PredictedObject",
        "PredictedObjectKinematics",
        "PredictedObjects",
        "PredictedPath",
        "Shape",
        "TrackedObject",
        "TrackedObjectKinematics",
        "TrackedObjects",
    ),
}
NS_PER_S = 1_000_000_000
_CDR_HEADER_BYTES = 4  # encapsulation kind and options precede the payload


class ContractError(ScenarioError):
    """A message that does not fit the contract (cannot become the core type it stands for)."""


def msg_definitions_dir(package: str = ADVSIM_MSGS) -> Path:
    """The folder of ``package``/msg/*.msg: $ADVSIM_MSG_DIR (advsim_msgs only), msg_defs/ of the source
    tree, or the installed package's share folder."""
    override = os.environ.get(MSG_DIR_ENV) if package == ADVSIM_MSGS else None
    candidates = [Path(override)] if override else []
    candidates += [parent / "msg_defs" / package / "msg" for parent in Path(__file__).resolve().parents]
    for candidate in candidates:
        if candidate.is_dir() and any(candidate.glob("*.msg")):
            return candidate
    installed = _installed_msg_dir(package)
    if installed is not None:
        return installed
    raise ContractError(f"{package} message definitions not found (looked in {[str(c) for c in candidates]})")


def _installed_msg_dir(package: str) -> Path | None:
    """share/<package>/msg of an installed (colcon or venv) package, when ament_index can find it."""
    try:
        from ament_index_python.packages import get_package_share_directory

        folder = Path(get_package_share_directory(package)) / "msg"
    except (ImportError, LookupError, OSError, ValueError):  # not installed, or AMENT_PREFIX_PATH unset
        return None
    return folder if folder.is_dir() and any(folder.glob("*.msg")) else None


def _typesdict(package: str, stems: tuple[str, ...] | None = None) -> Typesdict:
    """Field definitions of a package's messages (all of its .msg files, or those named), parsed."""
    folder = msg_definitions_dir(package)
    paths = sorted(folder.glob("*.msg")) if stems is None else [folder / f"{stem}.msg" for stem in stems]
    types: Typesdict = {}
    for path in paths:
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as error:
            raise ContractError(f"{package} message definition {path} unreadable: {error}") from error
        types.update(get_types_from_msg(text, f"{package}/msg/{path.stem}"))
    return types


@functools.cache
def advsim_typesdict() -> Typesdict:
    """advsim_msgs' field definitions, parsed from the .msg files."""
    return _typesdict(ADVSIM_MSGS)


@functools.cache
def autoware_typesdict() -> Typesdict:
    """The Autoware messages' field definitions (AUTOWARE_MESSAGES), parsed from the .msg files."""
    types: Typesdict = {}
    for package, stems in AUTOWARE_MESSAGES.items():
        types.update(_typesdict(package, stems))
    return types


@functools.cache
def typestore() -> Typestore:
    """The shared typestore: ROS 2 Jazzy's types plus advsim_msgs and the Autoware messages (read-only
    after creation)."""
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(advsim_typesdict())
    store.register(autoware_typesdict())
    return store


def message(type_name: str, **fields: Msg) -> Msg:
    """A message object of the shared typestore; ``fields`` are its field values (scalars, arrays, nested
    messages), untyped like the message itself."""
    return typestore().types[type_name](**fields)


def encode(value: Msg) -> bytes:
    """CDR bytes of a typestore message object."""
    return bytes(typestore().serialize_cdr(value, value.__msgtype__))


def decode(raw: bytes | memoryview, type_name: str) -> Msg:
    """A typestore message object from CDR bytes; ContractError when they do not decode as that type."""
    try:
        return typestore().deserialize_cdr(raw, type_name)
    except Exception as error:  # rosbags raises several types for truncated or foreign bytes
        raise ContractError(f"bytes do not decode as {type_name}: {error}") from error


# ----------------------------------------------------------------------------- CDR written directly

# The stacks publish a plan and hundreds of tracks every sweep: their builders write CDR bytes
# themselves (the same bytes as encode() of the message objects, which cost tens of ms per sweep).
CDR_LE_HEADER = b"\x00\x01\x00\x00"  # encapsulation: plain CDR, little-endian (what encode() writes here)


def cdr_align(payload: bytearray, size: int) -> None:
    """Zero padding up to a multiple of size (offsets count from the payload, after the encapsulation)."""
    payload.extend(bytes(-len(payload) % size))


def cdr_string(payload: bytearray, text: str) -> None:
    encoded = text.encode()
    cdr_align(payload, 4)
    payload.extend(struct.pack("<I", len(encoded) + 1))
    payload.extend(encoded)
    payload.append(0)


def cdr_header(payload: bytearray, value_ns: int, frame_id: str) -> None:
    """A std_msgs/Header: its stamp, then its frame."""
    cdr_align(payload, 4)
    payload.extend(struct.pack("<iI", *divmod(int(value_ns), NS_PER_S)))
    cdr_string(payload, frame_id)


# ----------------------------------------------------------------------------- stamps and headers


def stamp_ns(time: Msg) -> int:
    """builtin_interfaces/Time (rclpy or rosbags object) as integer nanoseconds."""
    return int(time.sec) * NS_PER_S + int(time.nanosec)


def time_msg(value_ns: int) -> Msg:
    sec, nanosec = divmod(int(value_ns), NS_PER_S)
    return message(names.TIME, sec=sec, nanosec=nanosec)


def header_msg(value_ns: int, frame_id: str) -> Msg:
    return message(names.HEADER, stamp=time_msg(value_ns), frame_id=frame_id)


def clock_cdr(value_ns: int) -> bytes:
    return encode(message(names.CLOCK, clock=time_msg(value_ns)))


def header_stamp_ns(raw: bytes | memoryview) -> int:
    """Header stamp of a CDR message whose first field is std_msgs/Header, without decoding the rest."""
    little = raw[1] == 1  # encapsulation CDR_LE = 0x0001, CDR_BE = 0x0000
    sec, nanosec = struct.unpack_from("<iI" if little else ">iI", raw, _CDR_HEADER_BYTES)
    return int(sec) * NS_PER_S + int(nanosec)


def restamp(raw: bytes, value_ns: int) -> bytes:
    """A copy of a header-first CDR message with its header stamp replaced (frame and payload unchanged)."""
    little = raw[1] == 1
    sec, nanosec = divmod(int(value_ns), NS_PER_S)
    patched = bytearray(raw)
    struct.pack_into("<iI" if little else ">iI", patched, _CDR_HEADER_BYTES, sec, nanosec)
    return bytes(patched)


def after_stamp(raw: bytes | memoryview) -> memoryview:
    """Everything of a header-first CDR message after its header stamp (digests that must not see sim time)."""
    return memoryview(raw)[_CDR_HEADER_BYTES + 8 :]
