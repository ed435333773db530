"""Planning service (thesis §6.3.2): OMPL joint-space plans of one arm to a goal pose, executed with an F/T contact watchdog.

A ``pose`` :class:`CartesianTarget` on ``goal`` is a plan request: the service solves the
goal's IK and plans from the measured joints with OMPL (KPIECE1 or RRTConnect) on a
background thread, collision-checked with coal against the cell's declared fixtures (floor,
table) and the newest sensed ``cloud``; never against the simulation's object poses. A found
plan is followed at the control rate on ``joint_command`` (resource ``arm_<arm>``) and
aborted when the wrist force changes by ``abort_force``. Outcomes are events: ``success``
(executed), ``failure`` (no IK, no plan, or aborted; the detail says which) and ``contact``
on an abort. A ``stop`` target cancels.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from contactflow.embodiments.control.kinematics import Kinematics
from contactflow.embodiments.control.planning import (
    PLANNERS,
    ArmPlanner,
    CoalChecker,
    Obstacle,
    Plan,
    solve_ik,
)
from contactflow.embodiments.control.trajectory import TrajectoryFollower, TrajectoryParams
from contactflow.embodiments.messages import (
    CartesianTarget,
    JointCommand,
    JointState,
    PointCloud,
    Wrench,
)
from contactflow.embodiments.modules.cartesian_service import arm_of, for_arm, measured_q
from contactflow.embodiments.modules.sim_interface import COMMAND_PORT
from contactflow.embodiments.transforms import xyz_rpy_to_matrix
from contactflow.nodes.module import Layer, Module, ModuleIO, Port
from contactflow.nodes.status import Event, Status
from contactflow.nodes.wire import NDArray


class PlannerService(Module):
    """Plans its arm to each goal pose with OMPL and executes the plan, stopping on an unexpected contact."""

    abstract = True
    layer = Layer.SERVICE
    arm: ClassVar[str] = ""
    inputs = (
        Port("joint_state", JointState, "measured joints of the robot"),
        Port("goal", CartesianTarget, "pose goal of the controlled frame (world), or stop"),
        Port("cloud", PointCloud, "sensed obstacle points (world), newest one used"),
        Port("wrench", Wrench, "wrist F/T of the arm, for the contact watchdog"),
    )
    events = (Event.SUCCESS, Event.FAILURE, Event.CONTACT)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 200.0  # Hz, the joint control rate (§6.3.1)
        robot: str = "melfa"  # embodiment registry name
        planner: str = "KPIECE1"  # KPIECE1 (the thesis) or RRTConnect
        timeout: float = 2.0  # s of planning time per try
        tries: int = 2  # fresh plans before giving up (a sampling planner's time to a path has a long tail)
        speed: float = 0.5  # rad/s, joint speed bound of the execution
        abort_force: float = 8.0  # N, wrist force change that aborts the execution
        table: bool = True  # the cell has the standard table (a declared fixture)
        table_size: tuple[float, float, float] = (0.8, 1.4, 0.75)  # m, full sizes; top at z = size[2]
        table_xy: tuple[float, float] = (0.65, 0.0)  # m, centre
        seed: int = 1  # OMPL seed (> 0; OMPL takes it only before its first sample in the process)

    def __init__(self, name: str, params: Params | None = None) -> None:
        super().__init__(name, params)
        self.kin: Kinematics | None = None
        self.plan: Plan | None = None
        self.follower: TrajectoryFollower | None = None
        self._job: threading.Thread | None = None
        self._result: tuple[Plan | None, str] | None = None
        self._cancel = False

    def setup(self, io: ModuleIO) -> None:
        super().setup(io)

        p = self.params
        if p.planner not in PLANNERS:
            raise ValueError(f"{self.name}.params.planner: {p.planner!r} is not one of {sorted(PLANNERS)}")
        if p.tries < 1:
            raise ValueError(f"{self.name}.params.tries: {p.tries} (at least one plan is tried)")
        self.spec, self.arm_spec = arm_of(self)
        spec = self.spec
        self.base = xyz_rpy_to_matrix(spec.base_xyz, spec.base_rpy)
        self.kin = Kinematics(spec.urdf(), self.base)
        self.fixtures = [Obstacle("floor", "box", (10.0, 10.0, 0.1), xyz_rpy_to_matrix((0.0, 0.0, -0.05)))]
        if p.table:
            sx, sy, sz = p.table_size
            self.fixtures.append(Obstacle("table", "box", (sx, sy, sz), xyz_rpy_to_matrix((*p.table_xy, sz / 2))))

    def _plan(self, goal: np.ndarray, q_full: np.ndarray, cloud: np.ndarray | None) -> None:
        """Background job: IK of the goal, then an OMPL plan; leaves ``(plan, why_not)`` in ``_result``."""
        try:
            self._result = self._solve(goal, q_full, cloud)
        except Exception as exc:  # reported as a failed request; the service goes on
            self._result = (None, f"planning raised {type(exc).__name__}: {exc}")

    def _solve(self, goal: np.ndarray, q_full: np.ndarray, cloud: np.ndarray | None) -> tuple[Plan | None, str]:
        p, a = self.params, self.arm_spec
        kin = Kinematics(self.spec.urdf(), self.base)  # the job's own model: the step thread uses self.kin
        check = CoalChecker(kin, str(self.spec.urdf()), self.fixtures, cloud=cloud, parts=self.spec.collision_groups)
        q_goal = solve_ik(kin, a.joints, a.ee_frame, goal, q_full, check.valid, seed=p.seed)
        if q_goal is None:
            return None, "no collision-free IK solution for the goal"
        planner = ArmPlanner(kin, a.joints, check.valid, q_full)
        tries = 0
        while True:
            plan = planner.plan(q_full[planner.idx], q_goal, planner=p.planner, timeout=p.timeout, seed=p.seed)
            tries += 1
            if plan.success or not plan.timed_out or self._cancel or tries == p.tries:
                return plan, plan.why_not + (f" ({tries} tries)" if tries > 1 and not plan.success else "")

    def _request(self, t: CartesianTarget, q: np.ndarray) -> None:
        where = f"{self.name}: input 'goal' ({t.hdr.source or 'unknown source'})"
        if t.mode == "stop":
            self._cancel = self._job is not None
            self.follower = None
            return
        v = np.asarray(t.values, dtype=np.float64)
        if t.mode != "pose" or v.shape != (16,) or not np.isfinite(v).all() or t.frame != "world":
            raise ValueError(f"{where}: a plan goal is a world-frame pose target with 16 finite values "
                             f"(mode {t.mode!r}, frame {t.frame!r}, {v.shape[0]} values)")
        if self._job is not None:
            raise ValueError(f"{where}: a plan is still being computed")
        cloud_msg = self.io.latest("cloud")
        cloud = cloud_msg.points.numpy().astype(np.float64).reshape(-1, 3) if cloud_msg is not None else None
        self.follower, self._result, self._cancel = None, None, False
        self._job = threading.Thread(target=self._plan, args=(v.reshape(4, 4), q, cloud), daemon=True,
                                     name=f"plan-{self.name}")
        self._job.start()

    def step(self) -> Status:
        js = self.io.latest("joint_state")
        if js is None:
            return Status.RUNNING
        q = measured_q(self.kin, js, self.name)
        for t in self.io.take("goal"):
            if t.arm != self.arm:
                continue
            try:
                self._request(t, q)
            except ValueError as exc:
                self.io.log(str(exc))
                self.io.emit(Event.FAILURE, str(exc)[:500])
        if self._job is not None and not self._job.is_alive():
            self._job = None
            plan, why = self._result or (None, "planning raised")
            if not self._cancel:
                self._start(plan, why)
        if self.follower is not None:
            self._follow()
        return Status.RUNNING

    def _start(self, plan: Plan | None, why: str) -> None:
        self.plan = plan
        if plan is None or not plan.success:
            self.io.emit(Event.FAILURE, why)
            return
        self.follower = TrajectoryFollower(plan.waypoints, TrajectoryParams(
            max_velocity=self.params.speed, max_acceleration=self.arm_spec.max_acceleration,
            abort_force=self.params.abort_force))

    def _follow(self) -> None:
        f = self.follower
        w = self.io.latest("wrench")
        force = np.asarray(w.force) if w is not None and w.arm == self.arm else None
        q, qd = f.step(1.0 / self.params.rate_hz, force)
        if f.status == Status.FAILURE:
            self.follower = None
            self.io.emit(Event.CONTACT, f"arm {self.arm}: plan execution aborted on contact")
            self.io.emit(Event.FAILURE, f"aborted: {f.abort_reason}")
            return  # the interface holds the last target: the arm stops where it is
        self.io.publish(COMMAND_PORT, JointCommand(names=list(self.arm_spec.joints), position=NDArray.of(q),
                                                   velocity=NDArray.of(np.ascontiguousarray(qd)), source=self.name))
        if f.status == Status.SUCCESS:
            self.follower = None
            self.io.emit(Event.SUCCESS, f"plan of {len(f.waypoints)} waypoints executed",
                         {"planning_time": float(self.plan.planning_time), "length": float(self.plan.length)})


LeftArmPlanner = for_arm("LeftArmPlanner", PlannerService, "left")  # tombatossals, baxter
RightArmPlanner = for_arm("RightArmPlanner", PlannerService, "right")
SingleArmPlanner = for_arm("SingleArmPlanner", PlannerService, "arm")  # melfa
