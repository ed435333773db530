"""Choose mapped (perceptual): the next object of a contact map to go for, claimed on the map, and the approach over it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from contactflow.embodiments.primitives.base import (
    Primitive,
    hand_pose_for,
    pose6,
    top_grasp_pose,
    wall_yaws,
)
from contactflow.fusion.messages import MapClaim, MappedObjectInfo, ObjectMapMsg
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.module import Port
from contactflow.nodes.status import Event


class ChooseMapped(Primitive):
    """Picks an object of an object map (of a robot's or a cell's contact fusion with a ``map_region``:
    what its contacts touched, whoever touched it; the robot's own unless its ``objects`` input is
    wired to another, e.g. its cell's) and claims it there.

    Of the objects inside ``region`` that fewer than ``forget`` claims went for without a touch
    since (hands that came and found nothing), the one with the fewest such claims, then the one
    this robot touched longest ago (never first: an object it could not take waits while it
    tries the others), then the one seen most. SUCCESS with the hand pose that puts its grasp
    centre ``height`` over the object (the hand turned for ``walls`` as ``place_location`` does),
    the object's id and location; OBJECT_NOT_FOUND when the map holds no such object, FAILURE
    when no map came within ``wait`` s.
    """

    commands_arm = False
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.OBJECT_NOT_FOUND)
    inputs = (Port("objects", ObjectMapMsg, "an object map (unwired: the robot's own fusion's)"),)
    outputs = (Port("claim", MapClaim, "the object this robot goes for, to the map it chose it from"),)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        region: tuple[float, ...] = ()  # m, [xmin, ymin, xmax, ymax]: only objects over it ((): all)
        support_z: float = 0.75  # m, height of the support the objects stand on
        height: float = 0.1  # m, approach height of the grasp centre above the support
        yaw: float = 1.5707963267948966  # rad, top grasp yaw
        walls: tuple[float, ...] = ()  # m, [xmin, ymin, xmax, ymax] inner sides of the container grasped in (none: no walls)
        wall_margin: float = 0.055  # m, an object this close to a wall gets the hand's ``wall_side`` toward it
        wall_side: tuple[float, ...] = (1.0, 0.0)  # hand-frame (x, y) direction put toward a nearby wall (per hand, measured)
        forget: int = 3  # claims without a touch since, after which an object is not gone for (nothing there)
        wait: float = 2.0  # s for a map to come

        def validate(self) -> None:
            if self.region and (len(self.region) != 4 or self.region[0] > self.region[2] or self.region[1] > self.region[3]):
                raise ValueError(f"region: expected [xmin, ymin, xmax, ymax], got {list(self.region)}")
            if self.forget < 1 or self.wait <= 0:
                raise ValueError(f"forget={self.forget} must be >= 1 and wait={self.wait} > 0 s")

    @classmethod
    def default_input_keys(cls, ks: KeySpace, robot: str, name: str, params: Any) -> dict[str, str]:
        return {"objects": ks.fused(robot, "objects")}

    @classmethod
    def default_output_keys(cls, ks: KeySpace, robot: str, name: str, params: Any) -> dict[str, str]:
        return {"claim": ks.fused(robot, "claims")}

    def update(self) -> None:
        p = self.params
        msg = self.io.latest("objects") if self.io is not None else None
        if not isinstance(msg, ObjectMapMsg):
            if self.elapsed > p.wait:
                self.fail(f"no object map within {p.wait:g} s: does the contact fusion its objects input reads "
                          f"have a map_region?")
            return
        chosen = choose(msg.objects, self.r.name, p.region, p.forget)
        if chosen is None:
            self.fail(f"the map holds no object to go for ({len(msg.objects)} mapped)", event=Event.OBJECT_NOT_FOUND)
            return
        x, y, z = chosen.location
        assert self.io is not None
        self.io.publish("claim", MapClaim(map=msg.map, robot=self.r.name, object_id=chosen.id, location=list(chosen.location)))
        yaw = wall_yaws([p.yaw], (x, y), p.walls, p.wall_margin, p.wall_side)[0]
        T = hand_pose_for(self.r.spec.name, top_grasp_pose((x, y, p.support_z + p.height), yaw))
        self.succeed(f"object {chosen.id} at ({x:.3f}, {y:.3f}, {z:.3f})", **pose6(T), object_id=float(chosen.id),
                     object_x=x, object_y=y, object_z=z)


def choose(objects: list[MappedObjectInfo], robot: str, region: tuple[float, ...], forget: int) -> MappedObjectInfo | None:
    """The object ``robot`` goes for next (see :class:`ChooseMapped`), or None."""
    def over(o: MappedObjectInfo) -> bool:
        return not region or (region[0] <= o.location[0] <= region[2] and region[1] <= o.location[1] <= region[3])

    left = [o for o in objects if over(o) and o.claims < forget]
    return min(left, key=lambda o: (o.claims, o.touched.get(robot, -np.inf), -o.sightings), default=None)
