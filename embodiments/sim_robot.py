"""In-process facade over one simulated robot: arm and hand commands, sensors read from the physics.

``SimRobot`` is what primitives and benchmarks use in-process (``embodiments/API.md``). Its
controllers run as a world hook at the control rate (200 Hz, §6.3.1): every arm and hand
controller submits joint commands to the weighted :class:`JointCommandMixer`, external
sources may submit too, and the mixed targets drive the joints. Sensors always read the
physics. A detected fault stops the robot and raises ``Event.HARDWARE_FAILURE`` instead of
an exception.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.control.arm import ArmController, ArmMode
from contactflow.embodiments.control.kinematics import Kinematics
from contactflow.embodiments.control.mixer import JointCommandMixer
from contactflow.embodiments.facade import ArmFacade, RobotFacade
from contactflow.embodiments.faults import Fault, FaultMonitor, FaultParams
from contactflow.embodiments.registry import ArmSpec, HandSpec, RobotSpec
from contactflow.embodiments.sensors.camera import DepthCamera, DepthFrame
from contactflow.embodiments.sensors.encoders import Encoders
from contactflow.embodiments.sensors.ft import RobotDynamics, WrenchReading, WristFT
from contactflow.embodiments.sensors.ground_truth import GroundTruth, read_ground_truth
from contactflow.embodiments.sensors.tactile import TactileSensor
from contactflow.embodiments.world import World
from contactflow.nodes.status import Event, Status


@dataclass(frozen=True)
class SimRobotParams:
    control_rate: float = 200.0  # Hz, joint command mixing and controllers (§6.3.1)
    seed: int = 0
    settle_time: float = 0.1  # s simulated before the F/T sensors are tared
    mixer_timeout: float = 0.1  # s a command stays fresh
    hand_tolerance: float = 0.02  # fraction of each finger joint's range: target reached
    faults: FaultParams = FaultParams()
    watch_streams: bool = True  # sample the F/T and tactile streams every control tick, so the fault watchdog tells a silent one (a predictor, which reads its sensors only to compare, does without)


class _Commanded:
    """A part of the robot that runs one command at a time and reports its :class:`Status`."""

    robot: SimRobot
    status: Status

    def done(self) -> bool:
        return self.status in (Status.SUCCESS, Status.FAILURE)

    def wait(self, timeout: float) -> Status:
        """Step the world until the command finishes or ``timeout`` s pass."""
        dt = 1.0 / self.robot.params.control_rate
        t_end = self.robot.time + timeout
        while not self.done() and self.robot.time < t_end and not self.robot.failed:
            self.robot.step(dt)
        return self.status


class ArmHandle(ArmFacade, _Commanded):
    """Commands and state of one arm (see API.md); its :class:`ArmController` runs in the control hook."""

    def __init__(self, robot: SimRobot, spec: ArmSpec) -> None:
        self.robot, self.spec = robot, spec
        self.name = spec.name
        self.joints = spec.joints
        self.home = spec.home
        self._sidx = robot.art.indices(spec.joints)
        self._kidx = robot.kin.q_index(spec.joints)
        self._streamed_at: float | None = None  # s, the time of the last streamed target still driving the arm
        self.ctl = ArmController(robot._ctl_kin, spec, measured=robot._kin_q, target=lambda: robot.mixer.q[self._sidx],
                                 on_contact=lambda detail: robot._event(Event.CONTACT, detail))

    @property
    def _failed(self) -> bool:
        return self.robot.failed

    # -- state -----------------------------------------------------------------------------
    def q(self) -> np.ndarray:
        return self.robot._q_s[self._sidx].copy()

    def qd(self) -> np.ndarray:
        return self.robot._qd_s[self._sidx].copy()

    @property
    def q_cmd(self) -> np.ndarray:
        return self.ctl.q_cmd

    def stream(self, q: np.ndarray, qd: np.ndarray) -> None:
        """A joint position and velocity target from a controller elsewhere, for the coming tick.

        The position is held until the next target; the velocity only for that tick: a stream
        that stops leaves the arm holding its last position, not drifting at its last velocity.
        """
        self.ctl.stop()
        self.ctl.q_cmd = np.asarray(q, dtype=np.float64).copy()
        self._submit(self.ctl.q_cmd, np.asarray(qd, dtype=np.float64))
        self._streamed_at = self.robot.time

    def _submit(self, q: np.ndarray, qd: np.ndarray) -> None:
        self.robot.mixer.submit(f"arm/{self.name}", self.joints, q, qd, 1.0, self.robot.time)

    # -- control tick ----------------------------------------------------------------------
    def _tick(self, dt: float) -> None:
        r = self.robot
        if self.ctl.mode == ArmMode.IDLE:
            if self._streamed_at is not None and self._streamed_at < r.time:
                # the stream stopped: hold its last position at rest
                self._submit(self.ctl.q_cmd, np.zeros(len(self.joints)))
                self._streamed_at = None
            return  # an idle arm sends nothing: the mixer holds the last target and other sources may drive it
        reading = r.ft(self.name) if self.spec.ft else None
        out = self.ctl.update(r._q_s[self._sidx], dt, None if reading is None else reading.force,
                              None if reading is None else reading.vector)
        if out is not None:
            self._submit(*out)


class HandHandle(_Commanded):
    """Commands and state of one hand (see API.md)."""

    def __init__(self, robot: SimRobot, spec: HandSpec) -> None:
        self.robot, self.spec = robot, spec
        self.name, self.kind, self.joints = spec.name, spec.kind, spec.joints
        self.preshapes = tuple(spec.preshapes)
        self._sidx = robot.art.indices(spec.joints)
        self._mimic = [(robot.art.joint(j), list(spec.joints).index(m), k) for j, m, k in spec.mimic]
        self.encoders = Encoders(robot.art, spec.joints, seed=robot.params.seed)
        self.goal = robot.art.qpos()[self._sidx].copy()
        self.q_cmd = self.goal.copy()
        self.status = Status.IDLE
        self._still = 0.0
        self._submit = False
        self._lim = robot.art.force_limit[self._sidx].copy()
        self.effort = 1.0  # 0..1, the finger drives' force limit last commanded (a gripper's motor effort)
        self._tol = robot.params.hand_tolerance * (robot.art.upper[self._sidx] - robot.art.lower[self._sidx])

    def positions(self) -> np.ndarray:
        return self.encoders.read()[0]

    def set_fingers(self, q: np.ndarray, effort: float = 1.0) -> None:
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (len(self.joints),):
            raise ValueError(f"hand {self.name}: set_fingers needs {len(self.joints)} values, got shape {q.shape}")
        if not 0.0 < effort <= 1.0:
            raise ValueError(f"hand {self.name}: effort must be in (0, 1], got {effort}")
        art = self.robot.art
        self.effort = float(effort)
        lim = self._lim * effort
        for k, i in enumerate(self._sidx):
            art.force_limit[i] = lim[k]
            art.joints[int(i)].set_drive_property(float(art.kp[i]), float(art.kd[i]), float(lim[k]), "force")
        for i, _m, _k in self._mimic:
            art.force_limit[i] = lim[0]
            art.joints[i].set_drive_property(float(art.kp[i]), float(art.kd[i]), float(lim[0]), "force")
        self.goal = np.clip(q, art.lower[self._sidx], art.upper[self._sidx])
        self.status, self._still, self._submit = Status.RUNNING, 0.0, True
        if self.robot.failed:
            self.status = Status.FAILURE

    def preshape(self, name: str, effort: float = 1.0) -> None:
        if name not in self.spec.preshapes:
            raise ValueError(f"hand {self.name}: unknown preshape {name!r} (known: {list(self.preshapes)})")
        self.set_fingers(np.asarray(self.spec.preshapes[name]), effort)

    def open(self) -> None:
        self.preshape("open")

    def close(self, effort: float = 1.0) -> None:
        self.preshape("closed", effort)

    def _tick(self, dt: float) -> None:
        r = self.robot
        if not self._submit:
            return
        if self.status != Status.RUNNING and np.array_equal(self.q_cmd, self.goal):
            return  # reached: the mixer holds the target
        step = self.spec.max_velocity * dt
        self.q_cmd = self.q_cmd + np.clip(self.goal - self.q_cmd, -step, step)
        names = list(self.joints)
        qs = list(self.q_cmd)
        for i, m, k in self._mimic:
            names.append(r.art.joint_names[i])
            qs.append(k * self.q_cmd[m])
        r.mixer.submit(f"hand/{self.name}", names, np.asarray(qs), None, 1.0, r.time)
        if self.status == Status.RUNNING and np.allclose(self.q_cmd, self.goal):
            q = r._q_s[self._sidx]
            qd = r._qd_s[self._sidx]
            if np.all(np.abs(q - self.goal) < self._tol):
                self.status = Status.SUCCESS
            elif np.abs(qd).max() < 0.03 * self.spec.max_velocity:  # fingers stalled against an object
                self._still += dt
                if self._still > 0.1:
                    self.status = Status.SUCCESS  # blocked by an object: the grasp closed on it
            else:
                self._still = 0.0


class HeadHandle:
    """The pan-tilt head that carries the cameras: joint state, gaze Jacobians and joint targets (see API.md)."""

    def __init__(self, robot: SimRobot, joints: tuple[str, ...]) -> None:
        self.robot = robot
        self.joints = tuple(joints)
        self._sidx = robot.art.indices(self.joints)
        self._kidx = robot.kin.q_index(self.joints)  # fixed base, nq == nv: also the Jacobian's columns
        self.lower = robot.art.lower[self._sidx].copy()
        self.upper = robot.art.upper[self._sidx].copy()

    def q(self) -> np.ndarray:
        return self.robot._q_s[self._sidx].copy()

    def jacobian(self, frame: str) -> np.ndarray:
        """6 x len(joints) Jacobian of ``frame`` (linear, then angular velocity, world axes) in the head joints."""
        self.robot._sync_kin()
        return self.robot.kin.jacobian(frame)[:, self._kidx]

    def move_joints(self, q: np.ndarray) -> None:
        """Joint position targets, clipped to the joint limits; held until the next one."""
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (len(self.joints),):
            raise ValueError(f"head: move_joints needs {len(self.joints)} values, got shape {q.shape}")
        r = self.robot
        r.mixer.submit("head", self.joints, np.clip(q, self.lower, self.upper), None, 1.0, r.time)


class SimRobot(RobotFacade):
    """One robot in a :class:`World`, with controllers, sensors and fault handling."""

    def __init__(self, world: World, robot: str | RobotSpec, name: str | None = None, base: np.ndarray | None = None,
                 params: SimRobotParams | None = None) -> None:
        self.world = world
        self.params = params or SimRobotParams()
        self.art = world.add_robot(robot, name=name, base=base)
        self.spec: RobotSpec = self.art.spec
        self.name = self.art.name
        self.kin = Kinematics(self.spec.urdf(), self.art.base)
        self._ctl_kin = Kinematics(self.spec.urdf(), self.art.base)  # the controllers' model, at commanded joints
        self._s2k = self.kin.q_index(self.art.joint_names)
        self._q_s = self.art.qpos()
        self._qd_s = self.art.qvel()
        self._kin_stamp = -1
        self.mixer = JointCommandMixer(self.art.joint_names, timeout=self.params.mixer_timeout)
        self.mixer.hold(self._q_s)
        self._arms = {a.name: ArmHandle(self, a) for a in self.spec.arms}
        self._hands = {h.name: HandHandle(self, h) for h in self.spec.hands}
        self.head = HeadHandle(self, self.spec.head_joints) if self.spec.head_joints else None
        self._ft_of_arm: dict[str, WristFT] = {}
        dynamics = None  # one Newton-Euler pass a physics step for the robot's measuring wrists (none if estimated)
        for a in self.spec.arms:
            if a.ft:
                f = self.spec.ft(a.ft)
                if not f.estimated:
                    dynamics = dynamics or RobotDynamics(self.art, self.kin)
                self._ft_of_arm[a.name] = WristFT(self.art, f, seed=self.params.seed + len(self._ft_of_arm),
                                                  kin=self.kin, arm_joints=a.joints, dynamics=dynamics)
        self._tactile = {h.name: TactileSensor(self.art, h) for h in self.spec.hands}
        self._cameras: dict[str, DepthCamera] = {}
        watched = np.zeros(len(self.art.joint_names), bool)
        for a in self.spec.arms:
            watched[self.art.indices(a.joints)] = True
        self.monitor = FaultMonitor(self.art.joint_names, self.art.lower, self.art.upper, watched, self.params.faults)
        self.failed = False
        self.failure = ""
        self.events: list[tuple[float, Event, str]] = []
        self._nan_injected = False
        self._every = max(1, int(round(1.0 / (self.params.control_rate * world.params.timestep))))
        world.add_hook(self._hook)
        self.step(self.params.settle_time)
        for f in self._ft_of_arm.values():
            self._sync_kin()
            f.tare()

    # -- time ------------------------------------------------------------------------------
    @property
    def time(self) -> float:
        return self.world.time

    def step(self, dt: float) -> None:
        """Advance the world by ``dt`` seconds (all robots in it)."""
        self.world.step(max(1, int(round(dt / self.world.params.timestep))))

    def _hook(self, world: World) -> None:
        if world.steps % self._every:
            return
        self._control(self._every * world.params.timestep)

    # -- sensors ---------------------------------------------------------------------------
    def ft(self, arm: str) -> WrenchReading:
        try:
            sensor = self._ft_of_arm[arm]
        except KeyError:
            raise KeyError(f"robot {self.name}: arm {arm!r} has no F/T sensor") from None
        if sensor.spec.estimated:
            self._sync_kin()
        return sensor.read(self.time)

    def tare_ft(self, arm: str) -> None:
        self._sync_kin()
        self._ft_of_arm[arm].tare()

    def tactile(self, hand: str) -> dict[str, np.ndarray]:
        try:
            sensor = self._tactile[hand]
        except KeyError:
            raise KeyError(f"robot {self.name}: no hand {hand!r}") from None
        return sensor.sample(self.time, self.world.contacts_of(sensor.bodies), self.world.params.timestep)

    def _camera(self, name: str) -> DepthCamera:
        if name not in self._cameras:
            spec = self.spec.camera(name)
            self._cameras[name] = DepthCamera(self.world, spec, self.art.links[spec.link])
        return self._cameras[name]

    def camera(self, name: str = "kinect", labels: bool = True) -> DepthFrame:
        """The latest frame; a frame older than the sensor timeout means the stream is lost (hardware failure).
        ``labels``: which body each pixel hit (evaluation only; a frame without them renders cheaper)."""
        cam = self._camera(name)
        frame = cam.read(self.time, labels)
        self._watch_camera(name, cam)
        return frame

    def _watch_camera(self, name: str, cam: DepthCamera) -> None:
        # the camera streams while someone reads it: its watchdog runs on each request
        fault = self.monitor.silent_streams(self.time, {f"camera {name}": cam.stamp})
        if fault is not None and not self.failed:
            self._fail(fault)

    def depth(self, name: str = "kinect") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(depth (H, W), K, camera pose) of camera ``name`` now, without a full frame's points and
        labels (a depth stream's frame); the stream's watchdog runs as for :meth:`camera`."""
        cam = self._camera(name)
        depth, Twc = cam.read_depth(self.time)
        self._watch_camera(name, cam)
        return depth, cam.K, Twc

    def ground_truth(self) -> GroundTruth:
        """Object poses and true contacts — evaluation only."""
        return read_ground_truth(self.world)

    def submit_joint_command(self, source: str, names: list[str], q: np.ndarray, qd: np.ndarray | None = None,
                             weight: float = 1.0) -> None:
        """An external joint command mixed with the arm/hand controllers' commands (§6.3.1)."""
        self.mixer.submit(source, names, q, qd, weight, self.time)

    def joint_state(self) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
        """(names, positions, velocities, efforts) of every active joint, measured now (not at the last control tick)."""
        self._sync_kin()
        return list(self.art.joint_names), self._q_s.copy(), self._qd_s.copy(), self.art.drive_efforts()

    # -- kinematics ------------------------------------------------------------------------
    def _kin_q(self) -> np.ndarray:
        q = self.kin.q.copy()
        q[self._s2k] = self._q_s
        return q

    def kin_q_cmd(self) -> np.ndarray:
        """The model's joints: measured, with each arm at its commanded joints (where plans start)."""
        q = self._kin_q()
        for a in self._arms.values():
            q[a._kidx] = a.q_cmd
        return q

    def _sync_kin(self) -> None:
        """Bring ``kin`` to the measured joint state (once per physics step)."""
        if self._kin_stamp == self.world.steps:
            return
        if not self._nan_injected:
            self._q_s, self._qd_s = self.art.qpos(), self.art.qvel()
        self.kin.update(self._kin_q())
        self._kin_stamp = self.world.steps

    def fixtures(self) -> list:
        """The cell's fixtures at their declared pose (planning obstacles)."""
        from contactflow.embodiments.control.planning import fixtures_from_world

        return fixtures_from_world(self.world)

    def add_task_frame(self, name: str, parent: str, T: np.ndarray) -> None:
        """A named frame at ``T`` (4x4) relative to ``parent``, usable in every ``frame=`` argument."""
        self.kin.add_task_frame(name, parent, T)
        self._ctl_kin.add_task_frame(name, parent, T)

    # -- control and faults ----------------------------------------------------------------
    def _event(self, event: Event, detail: str) -> None:
        self.events.append((self.time, event, detail))

    def _control(self, dt: float) -> None:
        if self.failed:
            return
        q, qd = self.art.qpos(), self.art.qvel()
        if self._nan_injected:
            q = q.copy()
            q[0] = np.nan
        fault = self.monitor.check(self.time, q, qd, self.art.target,
                                   self._poll_streams() if self.params.watch_streams else None)
        if fault is not None:
            self._fail(fault)
            return
        self._q_s, self._qd_s = q, qd
        try:
            for a in self._arms.values():
                a._tick(dt)
            for h in self._hands.values():
                h._tick(dt)
            mq, mqd, mask = self.mixer.mix(self.time)
        except (np.linalg.LinAlgError, FloatingPointError, ValueError) as exc:
            # a controller fed by a corrupted state: a fault of the robot, not a crash of the world
            self._fail(Fault("nan", f"controller error: {exc}"))
            return
        if not (np.all(np.isfinite(mq)) and np.all(np.isfinite(mqd))):
            self._fail(Fault("nan", "non-finite joint command"))
            return
        if mask.any():
            idx = np.nonzero(mask)[0]
            self.art.set_targets(idx, mq[idx], mqd[idx])

    def _poll_streams(self) -> dict[str, float]:
        """Take the F/T and tactile streams' samples at the control rate; the stamps of their latest samples."""
        stamps = {}
        for arm, f in self._ft_of_arm.items():
            if f.spec.estimated and not self._nan_injected:
                self._sync_kin()
            f.read(self.time)
            stamps[f"F/T {arm}"] = f.stamp
        for hand, tac in self._tactile.items():
            if tac.pads:
                tac.sample(self.time, self.world.contacts_of(tac.bodies), self.world.params.timestep)
                stamps[f"tactile {hand}"] = tac.stamp
        return stamps

    def _fail(self, fault: Fault) -> None:
        self.failed = True
        self.failure = f"{fault.kind}: {fault.detail}"
        self.art.freeze()
        for a in self._arms.values():
            a.ctl.fail()
        for h in self._hands.values():
            if h.status == Status.RUNNING:
                h.status = Status.FAILURE
        self._event(Event.HARDWARE_FAILURE, self.failure)

    def inject_fault(self, kind: str, joint: str | None = None, sensor: str | None = None) -> None:
        """Test hook: ``nan`` (encoders return NaN), ``explode`` (a joint is kicked to a huge speed),
        ``stuck_joint`` (a joint is locked where it is), ``sensor_loss`` (``sensor`` = an arm's F/T, a hand's
        tactile arrays or a camera stops producing samples)."""
        if kind == "nan":
            self._nan_injected = True
        elif kind == "explode":
            qd = self.art.qvel()
            qd[self.art.joint(joint or self.art.joint_names[0])] = 1e3
            self.art.articulation.set_qvel(qd)
        elif kind == "stuck_joint":
            i = self.art.joint(joint or self.spec.arms[0].joints[0])
            q = float(self.art.qpos()[i])
            self.art.joints[i].set_limits([[q - 1e-4, q + 1e-4]])
        elif kind == "sensor_loss":
            # the sensor itself stops producing samples; the stream watchdog has to notice
            name = sensor or next(iter(self._ft_of_arm), "")
            cameras = [c.name for c in self.spec.cameras]
            if name in self._ft_of_arm:
                self._ft_of_arm[name].lost = True
            elif name in self._tactile and self._tactile[name].pads:
                self._tactile[name].lost = True
            elif name in cameras:
                self._camera(name).lost = True
            else:
                raise ValueError(f"robot {self.name}: no sensor {name!r} (F/T by arm: {list(self._ft_of_arm)}, "
                                 f"tactile by hand: {[h for h, t in self._tactile.items() if t.pads]}, cameras: {cameras})")
        else:
            raise ValueError(f"unknown fault kind {kind!r} (nan | explode | stuck_joint | sensor_loss)")
