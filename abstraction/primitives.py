"""Abstract primitives (thesis Table 7.1), motion types and the two terminal state types."""

from __future__ import annotations

from enum import StrEnum


class AbstractPrimitive(StrEnum):
    """Embodiment-independent primitive actions (Table 7.1; slide from Tables 7.3-7.4)."""

    MOVE = "move"  # move without object
    TRANSPORT = "transport"  # move with object
    PLACE = "place"  # place down object
    PUSH = "push"  # push object
    GRASP = "grasp"  # grasp object
    RELEASE = "release"  # release object
    SLIDE = "slide"  # slide object over a surface

    @property
    def moves_arm(self) -> bool:
        """All primitives except grasp and release are arm motions (§7.2)."""
        return self not in (AbstractPrimitive.GRASP, AbstractPrimitive.RELEASE)

    @property
    def needs_target(self) -> bool:
        """Whether a target (or path) is required; move, push and grasp default to the object."""
        return self in (AbstractPrimitive.TRANSPORT, AbstractPrimitive.PLACE, AbstractPrimitive.SLIDE)


class Terminal(StrEnum):
    """Special state types that end an abstract task (§7.2.1)."""

    SUCCESS = "success"
    FAILURE = "failure"


class Movement(StrEnum):
    """Motion types (§7.2): how the arm may reach its target."""

    FREE = "free"  # any (collision-free) path
    GUARDED = "guarded"  # Cartesian straight line, stopping on contact
    CONSTRAINED = "constrained"  # rotational DOF kept constant (e.g. liquid containers)


STATE_PROPERTIES: dict[AbstractPrimitive, tuple[frozenset[str], frozenset[str]]] = {
    # (required, optional) properties besides movement/timeout/object (Table 7.1)
    AbstractPrimitive.MOVE: (frozenset(), frozenset({"target", "path", "hand_shape"})),
    AbstractPrimitive.TRANSPORT: (frozenset(), frozenset({"target", "path", "hand_shape"})),
    AbstractPrimitive.PLACE: (frozenset(), frozenset({"target", "path", "hand_shape"})),
    AbstractPrimitive.PUSH: (frozenset(), frozenset({"target", "path", "hand_shape"})),
    AbstractPrimitive.SLIDE: (frozenset(), frozenset({"target", "path", "hand_shape"})),
    AbstractPrimitive.GRASP: (frozenset(), frozenset({"hand_shape", "object_size"})),
    AbstractPrimitive.RELEASE: (frozenset(), frozenset({"hand_opening", "hand_shape"})),
}
"""Properties each abstract primitive accepts; ``movement``, ``object`` and ``timeout`` apply to all."""

COMMON_PROPERTIES = frozenset({"movement", "object", "timeout"})
