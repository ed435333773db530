"""Shared shell of the generator modules: a SERVICE publishing one ``HypothesisCloud`` per reading."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from contactflow.fusion.hypotheses import Hypotheses
from contactflow.fusion.messages import HypothesisCloud
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import Array
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.wire import Message


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
