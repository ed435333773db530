"""The inputs a stage of the depth chain has yet to process (the newest few, the oldest served first), and its base class."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Generic, TypeVar

from contactflow.nodes.module import Module
from contactflow.nodes.params import ParamError

T = TypeVar("T")


class Backlog(Generic[T]):
    """Keeps up to ``depth`` inputs waiting; beyond that the oldest is dropped (and counted).

    A stage of the depth chain steps once per input; a step of another module of its node (the
    1 Hz plane fit) or a busy CPU can hold it past a frame. With ``depth`` 1 the newer frame
    replaces the waiting one and a frame is lost; with 2 or 3 the stage catches up on its
    next steps, one frame later, and the chain keeps the camera's rate.
    """

    def __init__(self, depth: int) -> None:
        if depth < 1:
            raise ValueError(f"backlog: depth={depth} must be >= 1")
        self._q: deque[T] = deque()
        self.depth = depth
        self.dropped = 0

    def add(self, items: list[T]) -> None:
        for item in items:
            if len(self._q) == self.depth:
                self._q.popleft()
                self.dropped += 1
            self._q.append(item)

    def next(self, items: list[T] | None = None) -> T | None:
        """Add ``items``, then the oldest waiting input (None when none waits)."""
        if items:
            self.add(items)
        return self._q.popleft() if self._q else None

    def push_back(self, item: T) -> None:
        """Return an input taken with :meth:`next` to the front (it could not be processed yet)."""
        self._q.appendleft(item)


class StreamStage(Module):
    """A stage of the depth chain: each input of its stream processed once, through a :class:`Backlog`
    of ``params.backlog`` inputs (made at ``start`` and ``reset``). A stage's ``Params`` extend
    :class:`StreamStage.Params`."""

    abstract = True

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 200.0  # Hz, how often it looks for a new input (each is processed once, at the camera's 30 Hz of §6.3.3)
        backlog: int = 3  # inputs kept waiting, served oldest first (1: only the newest); more let the stage catch up after a slow step instead of dropping frames

    def start(self) -> None:
        self.pending = self._backlog()

    def reset(self) -> None:
        self.pending = self._backlog()

    def _backlog(self) -> Backlog:
        if self.params.backlog < 1:
            raise ParamError(f"{self.name}.params.backlog: {self.params.backlog} must be >= 1")
        return Backlog(self.params.backlog)
