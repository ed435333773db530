"""Move arm to (§6.3.6): planned (OMPL) or inverse-kinematics move to a pose, stopping on a collision."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive, pose6
from contactflow.embodiments.primitives.motion import planning_cloud, pose_error, target_pose
from contactflow.nodes.status import Event, Status


class MoveTo(Primitive):
    """Move the controlled frame to ``target``, optionally stopping ``standoff`` m back along the target's z axis."""

    requires = Capability()
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.CONTACT)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        target: tuple[float, ...] = ()  # [x, y, z, roll, pitch, yaw] m, rad (world)
        standoff: float = 0.0  # m, stop this far back along the target z (approach) axis
        planning: bool = True  # use the OMPL planner (False: straight Cartesian line)
        planner: str = "KPIECE1"  # OMPL planner (thesis §3.3.2)
        planning_checks: int = 50_000  # state checks per plan search (2-4 s): a count, the same on any machine
        obstacles: tuple[float, ...] = ()  # obstacle point cloud the planner avoids, flat [x, y, z, ...] (world)
        sense_obstacles: bool = False  # also plan against the camera cloud (robot removed by the spherical model)
        speed: float = 0.1  # m/s Cartesian (rad/s joint speed when planned: 5x this)
        abort_force: float = 15.0  # N, unexpected contact
        tolerance: float = 0.01  # m, final position error accepted
        timeout: float = 20.0  # s
        guarded: bool = False  # a contact over abort_force ends the motion with SUCCESS (a guarded move)
        preshape: str = ""  # hand preshape taken at the start ("" = keep)
        rest_posture: bool = False  # planned: the goal's arm posture is solved from the home posture, not the current one

    def begin(self) -> None:
        p = self.params
        if p.preshape and self.hand_name:
            self.hand.preshape(p.preshape)
        self.goal = target_pose(self, p.target, "target")
        if p.standoff:
            self.goal[:3, 3] -= self.goal[:3, 2] * p.standoff
        if self.r.spec.arm(self.arm_name).ft:
            self.r.tare_ft(self.arm_name)
        self.planned = False
        if p.planning:
            cloud = planning_cloud(self, p.obstacles, "obstacles", p.sense_obstacles)
            plan = self.arm.plan(self.goal, planner=p.planner, checks=p.planning_checks, cloud=cloud,
                                 rest=p.rest_posture)
            if plan is not None:
                self.arm.execute(plan, abort_force=p.abort_force, speed=5 * p.speed)
                self.planned = True
        if not self.planned:
            self.arm.move_pose(self.goal, speed=p.speed)
        self.stage = "move"

    def update(self) -> None:
        p = self.params
        if self.elapsed > p.timeout:
            self.fail(f"not at the target after {p.timeout} s", event=Event.TIMEOUT)
            return
        # no trajectory follower watches the force of a Cartesian move: a straight one (planning off) that
        # met an obstacle pushed it until the joints wound up (hundreds of N). The Cartesian fallback of a
        # failed plan still goes on (the grasp bench's trials were measured with it)
        if (p.guarded or not p.planning) and not self.planned:
            f = float(np.linalg.norm(self.wrench_in("world")[:3]))
            if f >= p.abort_force:
                self.halt()
                if p.guarded:
                    self.emit_once(Event.CONTACT, f"guarded move stopped on contact (|F| = {f:.1f} N)")
                    self.succeed(contact=1.0, force=f, **pose6(self.r.frame_pose(self.ee_frame)))
                    return
                self.emit_once(Event.CONTACT, f"unexpected contact while moving (|F| = {f:.1f} N)")
                self.fail(f"motion stopped by an unexpected contact (|F| = {f:.1f} N)", force=f)
                return
        if not self.arm.done():
            return
        if self.arm.status is Status.FAILURE:
            if getattr(self.arm, "abort_reason", "") == "contact":
                self.emit_once(Event.CONTACT, "unexpected contact while moving")
                if p.guarded:
                    self.succeed(contact=1.0, **pose6(self.r.frame_pose(self.ee_frame)))
                    return
            self.fail(f"motion aborted ({getattr(self.arm, 'abort_reason', '')})")
            return
        cur = self.r.frame_pose(self.ee_frame)
        dp, dr = pose_error(cur, self.goal)
        if self.stage == "move" and self.planned and (dp > 0.002 or dr > 0.02):
            self.arm.move_pose(self.goal, speed=p.speed)
            self.stage = "refine"
            return
        if dp <= p.tolerance:
            self.succeed(position_error=dp, rotation_error=dr, planned=float(self.planned), **pose6(cur))
        else:
            self.fail(f"ended {dp:.3f} m from the target", position_error=dp)
