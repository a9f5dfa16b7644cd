"""The bag schema of the suite (docs/bags.md): topics, types, offered QoS, ``custom_data`` and types.

A FIPER bag is a rosbag2 directory (``metadata.yaml`` + one MCAP file, format version 9) holding some
of the topics below, each recorded with the QoS its publishers offer (rosbag2 ``offered_qos_profiles``):
``/fiper/rollout_events`` and ``/fiper/alarm`` as TRANSIENT_LOCAL, the others VOLATILE. The bag's
``custom_data`` (:class:`BagInfo`) says what the data is: task, shapes, action space, calibration,
code version, whether it is synthetic, and where it came from.
"""
from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import Nodetype, Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from fiper_ros import __version__
from fiper_ros.bagio.errors import BagError
from fiper_ros.interface.qos_spec import QosSpec

#: Version of this schema, stored as ``custom_data["fiper_schema"]``.
SCHEMA_VERSION = "1"


def _qos_time(duration: Any) -> QosTime:
    ns = int(duration.nanoseconds)
    return QosTime(ns // 1_000_000_000, ns % 1_000_000_000)


def bag_qos(profile: Any) -> Qos:
    """An rclpy QoS profile (e.g. a publisher's, from the ROS graph) as the ``rosbags`` value stored in
    ``offered_qos_profiles``; read by attribute, so this module needs no rclpy."""
    return Qos(
        history=QosHistory(int(profile.history)),
        depth=int(profile.depth),
        reliability=QosReliability(int(profile.reliability)),
        durability=QosDurability(int(profile.durability)),
        deadline=_qos_time(profile.deadline),
        lifespan=_qos_time(profile.lifespan),
        liveliness=QosLiveliness(int(profile.liveliness)),
        liveliness_lease_duration=_qos_time(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
    )


def offered_qos(spec: QosSpec) -> Qos:
    """The ``offered_qos_profiles`` value of a suite topic's QoS (:mod:`fiper_ros.interface.qos_spec`): the
    profile its publishers offer, as :func:`bag_qos` of the rclpy profile built from it."""
    zero = QosTime(0, 0)
    return Qos(history=QosHistory.KEEP_LAST, depth=spec.depth, reliability=QosReliability.RELIABLE,
               durability=QosDurability[spec.durability], deadline=zero, lifespan=zero,
               liveliness=QosLiveliness[spec.liveliness],
               liveliness_lease_duration=QosTime(spec.lease_ns // 1_000_000_000, spec.lease_ns % 1_000_000_000),
               avoid_ros_namespace_conventions=False)


@dataclass(frozen=True)
class BagInfo:
    """What a bag holds, stored as rosbag2 ``custom_data`` (string values) in ``metadata.yaml``.

    Attributes:
        task: Task name, e.g. ``"pretzel"``.
        batch_size: ``B``, sampled chunks per policy step.
        horizon: ``H``, chunk length.
        action_dim: ``D``, action dimension.
        exec_steps: ``h``, executed actions per chunk.
        embedding_dim: ``E``, observation embedding size.
        action_space: ``ee_position``, ``joint_position`` or ``joint_velocity``.
        calibration_hash: Content hash of the calibration the suite ran with ("" if none / unknown).
        synthetic: True for generated data (never from a robot).
        source: Where the data came from (converter and source path, ``fiper record``, ...).
        split: ``calibration``, ``test`` or "" (mixed / unknown).
        split_rule: How the split was made when the source gave none (``fiper convert`` drew it:
            :func:`fiper_ros.core.data_split.describe`); "" when the source gave it.
        rollout_sources: Rollout id -> source file name (converters), for traceability.
        policy: Model folder of the policy that produced the rollouts (``fiper collect``; "" otherwise).
        policy_hash: SHA-256 of that model's files (``policy.pt``, ``policy.yaml``).
        policy_data_hash: The model's training-data hash (``data_hash`` in its ``policy.yaml``).
        seed: Episode seed of a one-rollout bag (``fiper collect``; "" otherwise).
        code_version: ``fiper_ros.__version__`` of the writer.
    """

    task: str = ""
    batch_size: int = 0
    horizon: int = 0
    action_dim: int = 0
    exec_steps: int = 0
    embedding_dim: int = 0
    action_space: str = ""
    calibration_hash: str = ""
    synthetic: bool = False
    source: str = ""
    split: str = ""
    split_rule: str = ""
    rollout_sources: dict[str, str] = field(default_factory=dict)
    policy: str = ""
    policy_hash: str = ""
    policy_data_hash: str = ""
    seed: str = ""
    code_version: str = __version__

    def to_custom_data(self) -> dict[str, str]:
        """The rosbag2 ``custom_data`` mapping (every value a string)."""
        data = {"fiper_schema": SCHEMA_VERSION}
        for item in fields(self):
            value = getattr(self, item.name)
            if isinstance(value, bool):
                data[item.name] = "true" if value else "false"
            elif isinstance(value, dict):
                data[item.name] = json.dumps(value, sort_keys=True)
            else:
                data[item.name] = str(value)
        return data

    @classmethod
    def from_custom_data(cls, data: dict[str, Any] | None, where: str = "bag") -> BagInfo:
        """Parse ``custom_data``; keys of other tools are ignored, missing keys keep their defaults; a
        ``fiper_schema`` version other than :data:`SCHEMA_VERSION` is refused."""
        data = data or {}
        version = str(data.get("fiper_schema", SCHEMA_VERSION))
        if version != SCHEMA_VERSION:
            raise BagError(f"{where}: FIPER bag schema version {version!r} not supported (this code reads "
                           f"{SCHEMA_VERSION!r})")
        values: dict[str, Any] = {}
        try:
            for item in fields(cls):
                if item.name not in data:
                    continue
                raw = str(data[item.name])
                if item.type == "bool":
                    values[item.name] = raw.lower() == "true"
                elif item.type == "int":
                    values[item.name] = int(raw)
                elif item.name == "rollout_sources":
                    values[item.name] = {str(k): str(v) for k, v in json.loads(raw).items()}
                else:
                    values[item.name] = raw
        except (ValueError, AttributeError) as error:
            raise BagError(f"{where}: malformed custom_data: {error}") from error
        return cls(**values)


def message_definitions() -> Path:
    """The directory of the installed ``fiper_msgs`` ``.msg`` files."""
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory  # noqa: PLC0415

    try:
        return Path(get_package_share_directory("fiper_msgs")) / "msg"
    except PackageNotFoundError as error:
        raise BagError("fiper_msgs is not installed (source env.sh)") from error


@functools.cache
def typestore() -> Typestore:
    """A ``Stores.ROS2_JAZZY`` typestore with the ``fiper_msgs`` types registered from their .msg files."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict[str, Any] = {}
    for path in sorted(message_definitions().glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"fiper_msgs/msg/{path.stem}"))
    store.register(types)
    return store


def normalize_cdr(raw: bytes, msgtype: str) -> bytes:
    """Re-serialise rclpy CDR bytes with ``rosbags``: the same values, alignment padding zeroed.

    rclpy leaves padding bytes uninitialised, so bags written from rclpy messages would differ from
    run to run; bags written by the converters go through this to be byte-for-byte deterministic.
    """
    store = typestore()
    return bytes(store.serialize_cdr(store.deserialize_cdr(raw, msgtype), msgtype))


#: numpy types of the ``.msg`` primitive types whose name is not a numpy type name.
_NUMPY_TYPES = {"byte": "uint8", "octet": "uint8", "char": "uint8"}


def _store_message(store: Typestore, msg: Any, msgtype: str) -> Any:
    """``msg`` (a generated ROS message object) as the ``rosbags`` message of ``msgtype``, field by field."""
    values: dict[str, Any] = {}
    for name, (kind, detail) in store.fielddefs[msgtype][1]:
        value = getattr(msg, name)
        if kind == Nodetype.NAME:
            value = _store_message(store, value, detail)
        elif kind in (Nodetype.SEQUENCE, Nodetype.ARRAY):
            (item_kind, item), _ = detail
            if item_kind == Nodetype.NAME:
                value = [_store_message(store, v, item) for v in value]
            elif item[0] == "string":
                value = list(value)
            else:
                value = np.asarray(value, dtype=_NUMPY_TYPES.get(item[0], item[0]))
        values[name] = value
    return store.types[msgtype](**values)


def message_cdr(msg: Any, msgtype: str) -> bytes:
    """The CDR bytes of a generated ROS message object (e.g. from :mod:`fiper_ros.interface.conversions`),
    serialised by ``rosbags`` without rclpy: alignment padding zeroed, so the bytes are deterministic and equal to
    :func:`normalize_cdr` of rclpy's ``serialize_message``."""
    store = typestore()
    return bytes(store.serialize_cdr(_store_message(store, msg, msgtype), msgtype))
