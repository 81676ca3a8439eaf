"""Choosing the colour, depth and calibration topics of a log without flags.

Image topics are split by name into depth (``depth`` in the name) and colour (the rest,
minus infrared / disparity / mask streams). Among candidates the most preferred wins:
iai_kinect2 resolution ``qhd`` over ``hd`` over ``sd``, rectified over unrectified,
raw over ``/compressed`` (same pixels, cheaper to decode), colour over mono. A tie is
an error that lists the candidates and names the flag that settles it.
"""
from __future__ import annotations

import posixpath
import re

from planar_vo.core.errors import InputError

_RES_RANK = {"qhd": 0, "hd": 1, "sd": 2}
_NOT_COLOR = {"ir", "infra", "infra1", "infra2", "disparity", "mask", "segmentation", "label",
              "labels", "confidence"}


def _tokens(topic: str) -> list[str]:
    return [t for t in re.split(r"[/_\-.]+", topic.lower()) if t]


def _resolution(topic: str) -> str | None:
    for tok in _tokens(topic):
        if tok in _RES_RANK:
            return tok
    return None


def _base(topic: str) -> str:
    """Topic without an image_transport suffix (``/compressed``, ``/compressedDepth``)."""
    return re.sub(r"/(compressed|compressedDepth)$", "", topic)


def _color_rank(topic: str) -> tuple:
    toks = set(_tokens(topic))
    return (_RES_RANK.get(_resolution(topic) or "", 3),
            0 if "rect" in toks else 1,
            0 if toks & {"color", "colour", "rgb"} else 1,
            0 if _base(topic) == topic else 1)


def _depth_rank(topic: str, color_res: str | None) -> tuple:
    toks = set(_tokens(topic))
    res = _resolution(topic)
    return (0 if res == color_res else 1,
            _RES_RANK.get(res or "", 3),
            0 if toks & {"registered", "aligned"} else 1,
            0 if "rect" in toks else 1,
            0 if _base(topic) == topic else 1)


def _pick(candidates: list[str], rank, what: str, flag: str) -> str:
    ranked = sorted(candidates, key=rank)
    best = [t for t in ranked if rank(t) == rank(ranked[0])]
    if len(best) > 1:
        raise InputError(f"several {what} topics fit ({', '.join(best)}); choose one with {flag}")
    return best[0]


def choose_topics(image_topics: list[str], info_topics: list[str], *, color_topic: str | None = None,
                  depth_topic: str | None = None, info_topic: str | None = None,
                  source: str = "log") -> tuple[str, str, str | None]:
    """``(color, depth, info or None)`` from the image and calibration topics of a log.

    Flags override the choice but must name existing topics.
    """
    for flag, topic, pool in (("--color-topic", color_topic, image_topics),
                              ("--depth-topic", depth_topic, image_topics),
                              ("--info-topic", info_topic, info_topics)):
        if topic is not None and topic not in pool:
            listed = ", ".join(sorted(pool)) or "none"
            raise InputError(f"{source}: {flag} {topic} is not in the log (candidates: {listed})")
    depth_cands = [t for t in image_topics if "depth" in _tokens(t) or "depth" in t.lower()]
    color_cands = [t for t in image_topics if t not in depth_cands and not set(_tokens(t)) & _NOT_COLOR]
    if color_topic is None:
        if not color_cands:
            raise InputError(f"{source}: no colour image topic (sensor_msgs/Image or CompressedImage, "
                             f"foxglove RawImage or CompressedImage); image topics: "
                             f"{', '.join(image_topics) or 'none'}; name one with --color-topic")
        color_topic = _pick(color_cands, _color_rank, "colour", "--color-topic")
    if depth_topic is None:
        depth_cands = [t for t in depth_cands if t != color_topic]
        if not depth_cands:
            raise InputError(f"{source}: no depth image topic (a name containing 'depth'); image topics: "
                             f"{', '.join(image_topics) or 'none'}; name one with --depth-topic")
        res = _resolution(color_topic)
        depth_topic = _pick(depth_cands, lambda t: _depth_rank(t, res), "depth", "--depth-topic")
    if info_topic is None and info_topics:
        info_topic = _choose_info(color_topic, info_topics)
    return color_topic, depth_topic, info_topic


def _choose_info(color_topic: str, info_topics: list[str]) -> str:
    sibling = posixpath.join(posixpath.dirname(_base(color_topic)), "camera_info")
    if sibling in info_topics:
        return sibling
    if len(info_topics) == 1:
        return info_topics[0]

    def shared(t: str) -> int:
        return len(posixpath.commonprefix([t.split("/"), color_topic.split("/")]))
    return _pick(info_topics, lambda t: (-shared(t),), "calibration", "--info-topic")
