"""Shared shell of the generator modules: a SERVICE publishing one ``HypothesisCloud`` per reading."""

from __future__ import annotations

import functools
from typing import Any, ClassVar

import numpy as np

from contactflow.embodiments.messages import RobotModel
from contactflow.fusion.geometry import check_capsules
from contactflow.fusion.hypotheses import Hypotheses
from contactflow.fusion.messages import HypothesisCloud
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import Array
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.wire import Message

MAX_PART = 2.0  # m, the largest radius or length of one bi-sphere a robot model may carry


class GeneratorModule(Module):
    """Base of the generator shells. ``Params`` of subclasses carry ``robot`` (the robot whose
    contacts the cloud is about) and the generator's algorithm parameters.
    """

    abstract = True
    layer = Layer.SERVICE
    outputs: ClassVar[tuple[Port, ...]] = (Port("hypotheses", HypothesisCloud, "contact hypotheses, world frame"),)

    @classmethod
    def default_output_keys(cls, ks: KeySpace, robot: str, name: str, params: Any) -> dict[str, str]:
        """Clouds go to ``contacts/<robot>/<generator>``: the robot they are about, this module's name."""
        return {"hypotheses": ks.hypotheses(getattr(params, "robot", robot), name)}

    def publish_cloud(self, h: Hypotheses, link: str = "") -> None:
        assert self.io is not None
        self.io.publish("hypotheses", HypothesisCloud.of(h, self.params.robot, self.name, link))

    def stamp_of(self, msg: Message) -> float:
        """Time of a reading: its simulation stamp when set, else the node clock."""
        assert self.io is not None
        return msg.hdr.t_sim if msg.hdr.t_sim > 0 else self.io.now


def array_of(msg: Message | None, port: str, cols: int | tuple[int, ...], module: str) -> np.ndarray | None:
    """The (n, cols) float array of an ``Array`` input, or None; a clear error on a bad shape."""
    if msg is None:
        return None
    if not isinstance(msg, Array):
        raise TypeError(f"{module}: input {port!r} carries {type(msg).__name__}, expected Array")
    a = msg.array.numpy().astype(np.float64)
    allowed = (cols,) if isinstance(cols, int) else cols
    if a.ndim != 2 or a.shape[1] not in allowed:
        raise ValueError(f"{module}: input {port!r} has shape {a.shape}, expected (n, {'|'.join(map(str, allowed))})")
    if not np.isfinite(a).all():
        raise ValueError(f"{module}: input {port!r} contains NaN or inf")
    return a


def capsules_of(msg: Message | None, port: str, module: str, prefixes: tuple[str, ...] = ()) -> np.ndarray | None:
    """The (m, 8) bi-spheres ``[c1, r1, c2, r2]`` of a ``RobotModel`` input, or None.

    With ``prefixes`` only the links whose names start with one of them are kept (e.g. a hand).
    """
    if msg is None:
        return None
    if not isinstance(msg, RobotModel):
        raise TypeError(f"{module}: input {port!r} carries {type(msg).__name__}, expected RobotModel")
    where = f"{module}: input {port!r} ({msg.robot})"
    c1, c2 = msg.c1.numpy().reshape(-1, 3), msg.c2.numpy().reshape(-1, 3)
    r1, r2 = msg.r1.numpy().ravel(), msg.r2.numpy().ravel()
    m = len(msg.links)
    if not (c1.shape[0] == c2.shape[0] == r1.shape[0] == r2.shape[0] == m):
        raise ValueError(f"{where}: {m} links but c1 {c1.shape}, r1 {r1.shape}, c2 {c2.shape}, r2 {r2.shape}")
    caps = check_capsules(np.concatenate([c1, r1[:, None], c2, r2[:, None]], axis=1).astype(np.float64), where)
    # a link's bi-sphere is a robot's part: a message claiming a bigger one (a corrupted or hostile model) would
    # make the shape generators grid cubic metres at 5 mm, a loop stalled for minutes
    radius, length = caps[:, [3, 7]].max(axis=1, initial=0.0), np.linalg.norm(caps[:, 4:7] - caps[:, 0:3], axis=1)
    big = np.flatnonzero((radius > MAX_PART) | (length > MAX_PART))
    if big.size:
        raise ValueError(f"{where}: link {msg.links[big[0]]!r} has a bi-sphere of radius {radius[big[0]]:.3g} m and "
                         f"length {length[big[0]]:.3g} m; a part of a robot is at most {MAX_PART:g} m")
    return caps[_links_of(msg, prefixes, where)] if prefixes else caps


@functools.lru_cache(maxsize=64)
def _prefix_mask(links: tuple[str, ...], prefixes: tuple[str, ...]) -> np.ndarray:
    """Which of ``links`` start with one of ``prefixes`` (read-only): a robot's model names the same links in
    every message, and matching its hundred names to the prefixes at 20 Hz per generator cost more than the
    shapes of a resting robot."""
    keep = np.array([any(link.startswith(p) for p in prefixes) for link in links], dtype=bool)
    keep.setflags(write=False)
    return keep


def _links_of(msg: RobotModel, prefixes: tuple[str, ...], where: str) -> np.ndarray:
    """The mask of the links whose names start with one of ``prefixes``; none is an error."""
    keep = _prefix_mask(tuple(msg.links), tuple(prefixes))
    if not keep.any():
        raise ValueError(f"{where}: no link starts with {list(prefixes)} (links: {msg.links})")
    return keep


def link_groups(msg: Message, module: str, prefixes: tuple[str, ...]) -> list[np.ndarray]:
    """The bi-spheres of a ``RobotModel`` input per link name prefix (all of them as one group without
    prefixes): what moves together, so a shape computed from a group is redone only when it moves."""
    caps = capsules_of(msg, "robot_model", module)  # decoded and checked once
    if caps is None or not prefixes:
        return [] if caps is None else [caps]
    where = f"{module}: input 'robot_model' ({msg.robot})"
    return [caps[_links_of(msg, (p,), where)] for p in prefixes]


def frame_of(msg: RobotModel, frame: str, module: str) -> np.ndarray:
    """World pose (4, 4) of ``frame`` carried by a ``RobotModel`` input."""
    if frame not in msg.frames or msg.poses is None:
        raise ValueError(f"{module}: input 'robot_model' ({msg.robot}) has no pose of frame {frame!r} "
                         f"(frames: {msg.frames})")
    poses = msg.poses.numpy().reshape(-1, 4, 4)
    if poses.shape[0] != len(msg.frames):
        raise ValueError(f"{module}: input 'robot_model' has {poses.shape[0]} poses for {len(msg.frames)} frames")
    T = poses[msg.frames.index(frame)].astype(np.float64)
    if not np.isfinite(T).all():
        raise ValueError(f"{module}: input 'robot_model' pose of {frame!r} is not finite")
    return T
