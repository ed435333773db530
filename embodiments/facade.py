"""What every robot facade shares (in-process ``SimRobot``, ``RemoteRobot`` over the key space): parts by name, frames."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np


class RobotFacade(ABC):
    """Arm and hand handles by name, and frames at the measured joints of the facade's ``kin`` model.

    A subclass sets ``name``, ``spec``, ``kin``, ``_arms`` and ``_hands`` and brings ``kin`` to
    the measured joints in ``_sync_kin``.
    """

    name: str
    spec: Any
    kin: Any
    _arms: dict[str, Any]
    _hands: dict[str, Any]

    @abstractmethod
    def _sync_kin(self) -> None:
        """Bring ``kin`` to the measured joints."""

    def arm(self, name: str):
        try:
            return self._arms[name]
        except KeyError:
            raise KeyError(f"robot {self.name}: no arm {name!r} (arms: {list(self._arms)})") from None

    def hand(self, name: str):
        try:
            return self._hands[name]
        except KeyError:
            raise KeyError(f"robot {self.name}: no hand {name!r} (hands: {list(self._hands)})") from None

    @property
    def arms(self) -> list[str]:
        return list(self._arms)

    @property
    def hands(self) -> list[str]:
        return list(self._hands)

    def finger_positions(self, hand: str) -> np.ndarray:
        return self.hand(hand).positions()

    def frame_pose(self, frame: str, relative_to: str = "world") -> np.ndarray:
        """Pose of any link, fixed frame or task frame at the measured joint state."""
        self._sync_kin()
        return self.kin.frame_pose(frame, relative_to)

    def camera_pose(self, name: str = "kinect") -> np.ndarray:
        """World pose of a camera's optical frame at the measured joint state."""
        spec = self.spec.camera(name)
        return self.frame_pose(spec.link) @ spec.optical_in_link()

    @property
    def spherical(self):
        """The posed spherical model (App. B) at the measured joints."""
        from contactflow.embodiments.spherical import SphericalModel

        if not hasattr(self, "_spherical"):
            self._spherical = SphericalModel.from_urdf(self.kin, str(self.spec.urdf()))
        self._sync_kin()
        self._spherical.update(self.kin)
        return self._spherical
