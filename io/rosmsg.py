"""ROS 1 and ROS 2 message (de)serialisation through the ``rosbags`` library.

The builders in :mod:`planar_vo.io.messages` return ROS 2 messages as plain dicts;
:func:`build` turns such a dict into a ``rosbags`` message object of either ROS version
(field names are matched case-insensitively, so ``k`` fills ROS 1's ``K``; fields the
dict lacks, such as ROS 1's ``Header.seq``, get their zero value). :func:`serialize`
then gives the bytes a ROS 1 bag (``ros1``) or a rosbag2 / ROS 2 MCAP (``cdr``) stores.

Decoded ``rosbags`` messages have the attribute layout the parsers in
:mod:`planar_vo.io.messages` read (``header.stamp.sec/nanosec``, ``k``/``K``, ...), so
every container shares one decoding path. :class:`Ros1DecoderFactory` plugs the ROS 1
profile of MCAP (``ros1msg`` schemas, ``ros1`` encoding) into the ``mcap`` reader.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

#: Message encodings by ROS version, as rosbags and MCAP name them.
ROS1, CDR = "ros1", "cdr"

_NUMPY = {"bool": np.bool_, "byte": np.uint8, "char": np.uint8, "int8": np.int8, "uint8": np.uint8,
          "int16": np.int16, "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32,
          "int64": np.int64, "uint64": np.uint64, "float32": np.float32, "float64": np.float64}


@lru_cache(maxsize=None)
def typestore(encoding: str):
    """The rosbags type store of ROS 1 Noetic (``ros1``) or ROS 2 Humble (``cdr``) messages."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    if encoding != ROS1:
        return get_typestore(Stores.ROS2_HUMBLE)
    store = get_typestore(Stores.ROS1_NOETIC)
    # rosbags' Noetic store lacks tf2_msgs (as ROS 1 defines it: /tf and /tf_static carry it).
    store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms\n",
                                      "tf2_msgs/msg/TFMessage"))
    return store


def full_type_name(name: str) -> str:
    """``sensor_msgs/Image`` (ROS 1 spelling) -> ``sensor_msgs/msg/Image``."""
    pkg, _, rest = name.partition("/")
    return name if rest.startswith("msg/") else f"{pkg}/msg/{rest}"


def _lookup(value: dict, name: str):
    if name in value:
        return value[name]
    lower = {k.lower(): v for k, v in value.items()}
    return lower.get(name.lower())


# rosbags.interfaces.Nodetype values (an IntEnum), spelt out: _field runs per field of every message.
_BASE, _NAME, _ARRAY = 1, 2, 3


def _field(store, desc, value):
    kind, detail = desc
    if kind == _NAME:
        return build(store, detail, value or {})
    if kind == _BASE:
        base = detail[0]
        if base == "string":
            return value or ""
        return _NUMPY[base](0).item() if value is None else value
    (sub_kind, sub_detail), length = detail
    if sub_kind == _BASE and sub_detail[0] in _NUMPY:
        arr = np.frombuffer(value, np.uint8) if isinstance(value, (bytes, bytearray, memoryview)) \
            else np.asarray(value if value is not None else [], dtype=_NUMPY[sub_detail[0]])
        if kind == _ARRAY and value is None:
            arr = np.zeros(length, dtype=arr.dtype)
        if kind == _ARRAY and arr.size != length:
            raise ValueError(f"a fixed array of {length} {sub_detail[0]} got {arr.size} values")
        return arr
    items = list(value or [])
    return [_field(store, (sub_kind, sub_detail), v) for v in items]


def build(store, typename: str, value: dict):
    """A rosbags message object of ``typename`` from a ROS 2-style dict (see module doc)."""
    _, fields = store.fielddefs[typename]
    return store.types[typename](**{name: _field(store, desc, _lookup(value, name))
                                    for name, desc in fields})


def serialize(encoding: str, typename: str, value) -> bytes:
    """``value`` (ROS 2-style dict, or a message :func:`build` made) serialised as ROS 1
    (``ros1``) or CDR (``cdr``)."""
    store = typestore(encoding)
    msg = build(store, typename, value) if isinstance(value, dict) else value
    if encoding == ROS1:
        return bytes(store.serialize_ros1(msg, typename))
    return bytes(store.serialize_cdr(msg, typename))


def ros1_msgdef(typename: str) -> tuple[str, str]:
    """``(definition text, md5sum)`` of a ROS 1 type, as bags and ROS 1 MCAP schemas store it."""
    return typestore(ROS1).generate_msgdef(typename)


class Ros1DecoderFactory:
    """``mcap`` decoder factory for the ROS 1 profile: types come from each schema's text."""

    def decoder_for(self, message_encoding: str, schema):
        if message_encoding != ROS1 or schema is None or schema.encoding != "ros1msg":
            return None
        from rosbags.typesys import Stores, get_typestore, get_types_from_msg
        typename = full_type_name(schema.name)
        store = get_typestore(Stores.EMPTY)  # one store per schema: definitions may differ
        store.register(get_types_from_msg(schema.data.decode("utf-8"), typename))
        return lambda data: store.deserialize_ros1(data, typename)
