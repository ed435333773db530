"""A SAPIEN physics world playing "reality": floor, table, objects and robots.

Scenes are physics-only (``PhysxCpuSystem``) unless the camera renders
(``WorldParams.camera_backend``): then the scene also has a render system, objects get visual
shapes matching their collision shapes and robots keep their URDF visuals. Robots are loaded
through the articulation builder (visual records dropped unless rendering); every robot gets
its own collision group with self-collision disabled (PhysX ignore bits would leak between
robots otherwise), joint friction is set to zero and gravity is compensated every
physics step, as a real arm controller does. Stepping is deterministic in lockstep;
``realtime=True`` makes :meth:`World.run` sleep to follow the wall clock.
"""

from __future__ import annotations

import time
from collections.abc import Collection
from dataclasses import dataclass

import numpy as np
import sapien

from contactflow.embodiments.registry import RobotSpec, collision_part, get
from contactflow.embodiments.sensors.render_camera import render_available
from contactflow.embodiments.transforms import pose_to_matrix, xyz_rpy_to_matrix
from contactflow.embodiments.urdf_compose import write
from contactflow.embodiments.visual_meshes import MAX_TRIANGLES, decimated


class WorldError(ValueError):
    """Bad scene description (names the object/robot and field)."""


@dataclass(frozen=True)
class WorldParams:
    timestep: float = 0.0025  # s, physics step (400 Hz)
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)  # m/s^2
    floor_z: float = 0.0  # m
    realtime: bool = False  # follow the wall clock in run()
    position_iterations: int = 10  # PhysX solver iterations of articulations (20 costs ~35 % more physics time)
    velocity_iterations: int = 2
    default_friction: float = 0.6
    camera_backend: str = "auto"  # auto | render | raycast: auto renders (SAPIEN) when a Vulkan device exists
    visual_triangles: int = MAX_TRIANGLES  # most triangles a robot's visual mesh is drawn with when rendering (0: as it is; visual_meshes)


@dataclass(frozen=True)
class ShapeSpec:
    """One primitive of an object; cylinders and capsules have their axis along local z."""

    kind: str  # box | cylinder | sphere | capsule
    size: tuple[float, ...]  # box: full x, y, z; cylinder/capsule: radius, length; sphere: radius
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m, in the object frame
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class ObjectSpec:
    """A rigid object: one or several shapes, mass, friction and initial pose."""

    name: str
    shapes: tuple[ShapeSpec, ...]
    mass: float = 0.2  # kg (ignored when static)
    friction: float = 0.6
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    static: bool = False
    category: str = "object"

    def volume(self) -> float:
        v = 0.0
        for s in self.shapes:
            if s.kind == "box":
                v += float(np.prod(s.size))
            elif s.kind == "sphere":
                v += 4.0 / 3.0 * np.pi * s.size[0] ** 3
            elif s.kind == "cylinder":
                v += np.pi * s.size[0] ** 2 * s.size[1]
            elif s.kind == "capsule":
                v += np.pi * s.size[0] ** 2 * s.size[1] + 4.0 / 3.0 * np.pi * s.size[0] ** 3
        return v


def box(name: str, size: tuple[float, float, float], xyz: tuple[float, float, float], mass: float = 0.2,
        friction: float = 0.6, rpy: tuple[float, float, float] = (0.0, 0.0, 0.0), static: bool = False) -> ObjectSpec:
    return ObjectSpec(name, (ShapeSpec("box", size),), mass, friction, xyz, rpy, static, "box")


def cylinder(name: str, radius: float, length: float, xyz: tuple[float, float, float], mass: float = 0.2,
             friction: float = 0.6) -> ObjectSpec:
    return ObjectSpec(name, (ShapeSpec("cylinder", (radius, length)),), mass, friction, xyz, category="cylinder")


def sphere(name: str, radius: float, xyz: tuple[float, float, float], mass: float = 0.1, friction: float = 0.6) -> ObjectSpec:
    return ObjectSpec(name, (ShapeSpec("sphere", (radius,)),), mass, friction, xyz, category="sphere")


def mug(name: str, xyz: tuple[float, float, float], mass: float = 0.3) -> ObjectSpec:
    """A household-like compound: cylinder body and a box handle."""
    return ObjectSpec(name, (ShapeSpec("cylinder", (0.04, 0.1)), ShapeSpec("box", (0.02, 0.012, 0.06), xyz=(0.05, 0.0, 0.0))),
                      mass, 0.6, xyz, category="mug")


def bottle(name: str, xyz: tuple[float, float, float], mass: float = 0.4) -> ObjectSpec:
    """A household-like compound: body cylinder, neck cylinder and cap sphere."""
    return ObjectSpec(name, (ShapeSpec("cylinder", (0.035, 0.16), xyz=(0.0, 0.0, -0.03)),
                             ShapeSpec("cylinder", (0.015, 0.06), xyz=(0.0, 0.0, 0.08)),
                             ShapeSpec("sphere", (0.017,), xyz=(0.0, 0.0, 0.11))), mass, 0.6, xyz, category="bottle")


_TO_X = sapien.Pose(q=[np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0])
"""PhysX cylinders and capsules lie along x; our specs put them along z."""


@dataclass(frozen=True)
class ScrewBottleSpec:
    """A bottle whose cap turns about the bottle axis; its body fixed to the world (held, as the other hand does in §3.4.2) or standing free."""

    name: str
    xyz: tuple[float, float, float]  # m, centre of the body's bottom face
    body_radius: float = 0.035  # m
    body_height: float = 0.16  # m
    neck_radius: float = 0.012  # m, the neck between the shoulder and the cap keeps fingers off the body
    neck_height: float = 0.04  # m
    cap_radius: float = 0.016  # m
    cap_height: float = 0.02  # m
    cap_mass: float = 0.02  # kg
    thread_friction: float = 0.1  # N m, Coulomb torque the thread resists turning with
    thread_damping: float = 0.02  # N m s/rad, viscous part of the thread's resistance
    thread_turns: float = 1.5  # turns (counter-clockwise seen from above) until the cap comes free
    friction: float = 1.0  # surface friction coefficient of body and cap
    fixed: bool = True  # the body welded in place; False: it stands free on its bottom and a hand has to hold it
    density: float = 500.0  # kg/m^3 of body and neck (a bottle part full: 0.3 kg for the default body)

    def cap_top(self) -> float:
        """World z of the cap's top face (m)."""
        return self.xyz[2] + self.body_height + self.neck_height + self.cap_height


def _sapien_pose(T: np.ndarray) -> sapien.Pose:
    return sapien.Pose(np.asarray(T, dtype=np.float64))


@dataclass
class SimObject:
    """An object in the world; ``pose()`` is ground truth, for evaluation only."""

    spec: ObjectSpec
    entity: sapien.Entity
    body: sapien.physx.PhysxRigidBaseComponent

    @property
    def name(self) -> str:
        return self.spec.name

    def pose(self) -> np.ndarray:
        return pose_to_matrix(self.entity.get_pose())

    def set_pose(self, T: np.ndarray) -> None:
        self.entity.set_pose(_sapien_pose(T))
        if isinstance(self.body, sapien.physx.PhysxRigidDynamicComponent):
            self.body.set_linear_velocity([0.0, 0.0, 0.0])
            self.body.set_angular_velocity([0.0, 0.0, 0.0])

    def mass(self) -> float:
        """kg; 0 for a static object."""
        return float(self.body.get_mass()) if isinstance(self.body, sapien.physx.PhysxRigidDynamicComponent) else 0.0

    def set_mass(self, kg: float) -> None:
        """Make a dynamic object ``kg`` heavy, its inertia scaled alike (the same shape, denser or lighter)."""
        if not isinstance(self.body, sapien.physx.PhysxRigidDynamicComponent):
            raise WorldError(f"object {self.name!r} is static: it has no mass to set")
        if not kg > 0:
            raise WorldError(f"object {self.name!r}: a mass must be > 0 kg, got {kg!r}")
        scale = kg / float(self.body.get_mass())
        self.body.set_inertia(np.asarray(self.body.get_inertia(), dtype=np.float64) * scale)
        self.body.set_mass(kg)


class SimArticulation:
    """A robot loaded in the world: joints by name, drives, gravity compensation, link poses."""

    def __init__(self, world: World, spec: RobotSpec, name: str, base: np.ndarray, group: int) -> None:
        self.world, self.spec, self.name, self.group = world, spec, name, group
        self.base = np.asarray(base, dtype=np.float64)
        scene = world.scene
        loader = scene.create_urdf_loader()
        loader.fix_root_link = True
        # a rendering world keeps the URDF visuals (same links and collisions, so the same joint order)
        urdf = write(spec.composition, visuals=True) if world.rendering else spec.urdf()
        builder = loader.load_file_as_articulation_builder(str(urdf))
        files = [r for lb in builder.link_builders for r in lb.visual_records if r.type == "file"]
        if not world.rendering:
            for lb in builder.link_builders:
                lb.visual_records = []
        elif world.params.visual_triangles > 0 and files:
            lighter = decimated([r.filename for r in files], world.params.visual_triangles)
            for r in files:
                r.filename = lighter[r.filename]
        self.articulation = builder.build()
        self.articulation.set_name(name)
        self.articulation.set_root_pose(_sapien_pose(self.base))
        self.articulation.set_solver_position_iterations(world.params.position_iterations)
        self.articulation.set_solver_velocity_iterations(world.params.velocity_iterations)
        self.links = {lk.get_name(): lk for lk in self.articulation.get_links()}
        self.joints = self.articulation.get_active_joints()
        self.joint_names = [j.get_name() for j in self.joints]
        self.index = {n: i for i, n in enumerate(self.joint_names)}
        self._forces, self._forces_step = np.zeros((0, 6)), -1
        self.lower = np.array([j.get_limits()[0][0] for j in self.joints])
        self.upper = np.array([j.get_limits()[0][1] for j in self.joints])
        self.kp = np.zeros(len(self.joints))
        self.kd = np.zeros(len(self.joints))
        self.force_limit = np.zeros(len(self.joints))
        self.target = np.zeros(len(self.joints))
        self.target_vel = np.zeros(len(self.joints))
        # what the drives were last given (position, velocity): a joint is written only when its target changes
        self._sent = np.full((2, len(self.joints)), np.nan)
        self.gravity_compensation = True
        self.frozen = False
        self._setup_collisions()
        self._setup_drives()
        self.set_home()

    # -- setup ---------------------------------------------------------------------------
    def _setup_collisions(self) -> None:
        finger_links: dict[str, float] = {}
        for h in self.spec.hands:
            names = set(h.fingertips) | {h.palm_link}
            names |= {self._child_link(j) for j in h.joints} | {self._child_link(m[0]) for m in h.mimic}
            for n in names:
                finger_links[n] = h.friction
        parts = self.spec.collision_groups

        def part_bit(lname: str) -> int:
            # links of one part share an ignore bit; different parts of the robot collide
            k = collision_part(lname, parts)
            return 1 << 30 if k == len(parts) else 1 << (29 - k)

        for lname, link in self.links.items():
            for shape in link.get_collision_shapes():
                g = shape.get_collision_groups()
                shape.set_collision_groups([g[0], g[1], g[2] | part_bit(lname), self.group])
                if lname in finger_links:
                    f = finger_links[lname]
                    shape.set_physical_material(sapien.physx.PhysxMaterial(f, f, 0.0))

    def _child_link(self, joint: str) -> str:
        for j in self.articulation.get_joints():
            if j.get_name() == joint:
                return j.get_child_link().get_name()
        raise WorldError(f"robot {self.name}: joint {joint!r} is not in {self.spec.urdf()}")

    def _setup_drives(self) -> None:
        for i, j in enumerate(self.joints):
            j.set_friction(0.0)
            self.kp[i], self.kd[i], self.force_limit[i] = 400.0, 40.0, 200.0
        for arm in self.spec.arms:
            for n in arm.joints:
                i = self.joint(n)
                self.kp[i], self.kd[i], self.force_limit[i] = arm.kp, arm.kd, arm.force_limit
        for h in self.spec.hands:
            for n in list(h.joints) + [m[0] for m in h.mimic]:
                i = self.joint(n)
                self.kp[i], self.kd[i], self.force_limit[i] = h.kp, h.kd, h.force_limit
                if h.armature > 0:
                    self.joints[i].set_armature([h.armature])
        for i, j in enumerate(self.joints):
            j.set_drive_property(float(self.kp[i]), float(self.kd[i]), float(self.force_limit[i]), "force")

    def joint(self, name: str) -> int:
        """SAPIEN index of an active joint."""
        try:
            return self.index[name]
        except KeyError:
            raise WorldError(f"robot {self.name}: no active joint {name!r}") from None

    def indices(self, names: tuple[str, ...] | list[str]) -> np.ndarray:
        return np.array([self.joint(n) for n in names], dtype=np.int64)

    def home_q(self) -> np.ndarray:
        q = np.clip(np.zeros(len(self.joints)), self.lower, self.upper)
        for arm in self.spec.arms:
            q[self.indices(arm.joints)] = arm.home
        for h in self.spec.hands:
            q[self.indices(h.joints)] = h.preshapes["open"]
            for joint, master, mult in h.mimic:
                q[self.joint(joint)] = mult * q[self.joint(master)]
        if self.spec.head_joints:
            q[self.indices(self.spec.head_joints)] = self.spec.head_home
        return q

    def set_home(self) -> None:
        self.set_state(self.home_q())

    # -- state ---------------------------------------------------------------------------
    def set_state(self, q: np.ndarray) -> None:
        """Teleport the joints to ``q`` (SAPIEN order) at rest and hold there."""
        q = np.asarray(q, dtype=np.float64)
        self.articulation.set_qpos(q)
        self.articulation.set_qvel(np.zeros_like(q))
        self.set_targets(np.arange(len(q)), q, np.zeros_like(q))

    def qpos(self) -> np.ndarray:
        return np.asarray(self.articulation.get_qpos(), dtype=np.float64)

    def qvel(self) -> np.ndarray:
        return np.asarray(self.articulation.get_qvel(), dtype=np.float64)

    def incoming_joint_forces(self) -> np.ndarray:
        """Each link's incoming joint wrench (n_links, 6), read once a physics step (every wrist F/T reads it)."""
        if self._forces_step != self.world.steps:
            self._forces = np.asarray(self.articulation.get_link_incoming_joint_forces(), dtype=np.float64)
            self._forces_step = self.world.steps
        return self._forces

    def set_targets(self, idx: np.ndarray, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        """Position (and velocity) drive targets of joints ``idx``."""
        if self.frozen:
            return
        q = np.clip(np.asarray(q, dtype=np.float64), self.lower[idx], self.upper[idx])
        qd = np.zeros_like(q) if qd is None else np.asarray(qd, dtype=np.float64)
        self.target[idx], self.target_vel[idx] = q, qd
        idx = np.asarray(idx)
        for k in np.flatnonzero((self._sent[0, idx] != q) | (self._sent[1, idx] != qd)):
            j = self.joints[int(idx[k])]
            j.set_drive_target(float(q[k]))
            j.set_drive_velocity_target(float(qd[k]))
        self._sent[0, idx], self._sent[1, idx] = q, qd

    def drive_efforts(self) -> np.ndarray:
        """Joint efforts of the position drives (what motor currents would show)."""
        q, qd = self.qpos(), self.qvel()
        tau = self.kp * (self.target - q) + self.kd * (self.target_vel - qd)
        return np.clip(tau, -self.force_limit, self.force_limit)

    def freeze(self) -> None:
        """Stop the robot: hold the current position with zero velocity (a fault stop)."""
        q = self.qpos()
        if not np.all(np.isfinite(q)):
            q = np.where(np.isfinite(q), q, self.target)
            self.articulation.set_qpos(q)
        self.articulation.set_qvel(np.zeros_like(q))
        self.frozen = False
        self.set_targets(np.arange(len(q)), q, np.zeros_like(q))
        self.frozen = True

    def unfreeze(self) -> None:
        self.frozen = False

    def link_pose(self, name: str) -> np.ndarray:
        try:
            return pose_to_matrix(self.links[name].get_entity_pose())
        except KeyError:
            raise WorldError(f"robot {self.name}: no link {name!r}") from None

    def pre_step(self) -> None:
        if self.gravity_compensation:
            self.articulation.set_qf(self.articulation.compute_passive_force(True, True))


class SimScrewBottle:
    """A screw-cap bottle: one articulation rooted at the body (fixed or free); the cap turns on a revolute joint about the bottle axis and lifts on a prismatic one.

    The thread's resistance is a viscous part (the turn joint's drive damping, with zero
    stiffness: PhysX integrates it implicitly, so it stays stable on a light cap) plus a
    Coulomb torque applied as a joint force before every step, smoothed below ``slip`` rad/s
    so the explicit force cannot make the cap chatter. The lift joint is locked until the cap
    has turned ``thread_turns``; then the cap comes free and can be pulled ``cap_travel`` off.
    ``cap_angle()`` and ``cap_lift()`` are ground truth, for evaluation only.
    """

    armature = 5e-3  # kg m^2, added cap inertia: keeps the explicit friction force stable
    cap_travel = 0.1  # m, how far a freed cap can be pulled along the bottle axis

    def __init__(self, world: World, spec: ScrewBottleSpec, group: int) -> None:
        self.world, self.spec = world, spec
        s = spec
        mat = sapien.physx.PhysxMaterial(s.friction, s.friction, 0.0)
        b = world.scene.create_articulation_builder()
        body = b.create_link_builder()
        body.set_name(f"{s.name}_body")
        half = s.body_height / 2
        body.add_cylinder_collision(pose=sapien.Pose([0.0, 0.0, half]) * _TO_X, radius=s.body_radius, half_length=half,
                                    material=mat, density=s.density)
        body.add_cylinder_collision(pose=sapien.Pose([0.0, 0.0, s.body_height + s.neck_height / 2]) * _TO_X,
                                    radius=s.neck_radius, half_length=s.neck_height / 2, material=mat, density=s.density)
        # joint frames turn and slide along their x axis: put it on the bottle axis (+z)
        axis = sapien.Pose(q=[np.cos(np.pi / 4), 0.0, -np.sin(np.pi / 4), 0.0])
        thread = b.create_link_builder(body)
        thread.set_name(f"{s.name}_thread")
        thread.set_joint_name(f"{s.name}_cap_turn")
        thread.set_mass_and_inertia(1e-3, sapien.Pose(), [1e-7, 1e-7, 1e-7])
        thread.set_joint_properties("revolute", limits=[[-np.inf, np.inf]],
                                    pose_in_parent=sapien.Pose([0.0, 0.0, s.cap_top() - s.xyz[2] - s.cap_height / 2]) * axis,
                                    pose_in_child=axis, damping=s.thread_damping)
        cap = b.create_link_builder(thread)
        cap.set_name(f"{s.name}_cap")
        cap.set_joint_name(f"{s.name}_cap_lift")
        cap.add_cylinder_collision(pose=_TO_X, radius=s.cap_radius, half_length=s.cap_height / 2, material=mat,
                                   density=s.cap_mass / (np.pi * s.cap_radius ** 2 * s.cap_height))
        cap.set_joint_properties("prismatic", limits=[[0.0, 0.0]], pose_in_parent=axis, pose_in_child=axis)
        if getattr(world, "rendering", False):
            body.add_cylinder_visual(pose=sapien.Pose([0.0, 0.0, half]) * _TO_X, radius=s.body_radius, half_length=half)
            body.add_cylinder_visual(pose=sapien.Pose([0.0, 0.0, s.body_height + s.neck_height / 2]) * _TO_X,
                                     radius=s.neck_radius, half_length=s.neck_height / 2)
            cap.add_cylinder_visual(pose=_TO_X, radius=s.cap_radius, half_length=s.cap_height / 2)
        b.set_initial_pose(sapien.Pose(list(s.xyz)))
        self.articulation = b.build(fix_root_link=s.fixed)
        self.articulation.set_name(s.name)
        self.turn, self.lift = self.articulation.get_active_joints()
        self.turn.set_armature([self.armature])
        self.turn.set_drive_property(0.0, s.thread_damping, 1e6, "force")
        self.lift.set_drive_property(0.0, 0.0, 0.0, "force")
        links = self.articulation.get_links()
        self.body_link, self.cap_link = links[0], links[2]
        # the cap rests on the neck it is screwed onto: the bottle's own parts never collide
        for link in links:
            for shape in link.get_collision_shapes():
                g = shape.get_collision_groups()
                shape.set_collision_groups([g[0], g[1], g[2] | (1 << 31), group])
        inertia = 0.5 * s.cap_mass * s.cap_radius ** 2 + self.armature
        # the smoothing keeps friction / slip * dt well below the cap's inertia
        self.slip = max(0.02, 2.0 * s.thread_friction * world.params.timestep / inertia)
        self.released = False

    @property
    def name(self) -> str:
        return self.spec.name

    def cap_angle(self) -> float:
        """Cap turn (rad), positive counter-clockwise seen from above: the unscrewing sense of a right-hand thread."""
        return float(self.articulation.get_qpos()[0])

    def cap_lift(self) -> float:
        """How far the cap has been pulled off the neck along the bottle axis (m)."""
        return float(self.articulation.get_qpos()[1])

    def cap_pose(self) -> np.ndarray:
        return pose_to_matrix(self.cap_link.get_entity_pose())

    def body_pose(self) -> np.ndarray:
        """The body's frame (world): the centre of its bottom face, z along the bottle axis."""
        return pose_to_matrix(self.body_link.get_entity_pose())

    def pre_step(self) -> None:
        w = float(self.articulation.get_qvel()[0])
        qf = np.zeros(2)
        qf[0] = -self.spec.thread_friction * float(np.clip(w / self.slip, -1.0, 1.0))
        self.articulation.set_qf(qf)
        if not self.released and self.cap_angle() >= 2.0 * np.pi * self.spec.thread_turns:
            self.released = True
            self.lift.set_limits([[0.0, self.cap_travel]])


def _rendering(backend: str) -> bool:
    """Whether a world with this camera backend gets a render system."""
    if backend == "raycast":
        return False
    if backend == "auto":
        return render_available()
    if backend == "render":
        if not render_available():
            raise WorldError("WorldParams.camera_backend is 'render' but no Vulkan device can render here")
        return True
    raise WorldError(f"WorldParams.camera_backend {backend!r} is not auto|render|raycast")


class World:
    """The physics scene. Add a table, objects and robots, then ``step``."""

    def __init__(self, params: WorldParams | None = None) -> None:
        self.params = params or WorldParams()
        if not (isinstance(self.params.visual_triangles, int) and self.params.visual_triangles >= 0):
            raise WorldError(f"WorldParams.visual_triangles {self.params.visual_triangles!r} is not a count >= 0")
        sapien.physx.set_body_config(sleep_threshold=0.0)
        sapien.physx.set_scene_config(gravity=np.array(self.params.gravity, dtype=np.float32))
        sapien.physx.set_default_material(self.params.default_friction, self.params.default_friction, 0.0)
        self.rendering = _rendering(self.params.camera_backend)
        systems = [sapien.physx.PhysxCpuSystem()] + ([sapien.render.RenderSystem()] if self.rendering else [])
        self.scene = sapien.Scene(systems)
        self.scene.set_timestep(self.params.timestep)
        self.scene.add_ground(self.params.floor_z, render=self.rendering)
        self.robots: dict[str, SimArticulation] = {}
        self.objects: dict[str, SimObject] = {}
        self.bottles: dict[str, SimScrewBottle] = {}
        self.time = 0.0
        self.steps = 0
        self._hooks: list = []
        self._contacts: list = []
        self._contacts_step = -1
        self._by_body: dict[int, list[int]] = {}  # id of a body -> indices of the last step's contacts it has
        self._by_body_step = -1
        self._t0_wall: float | None = None

    # -- building ------------------------------------------------------------------------
    def add_table(self, size: tuple[float, float, float] = (0.8, 1.4, 0.75), xyz: tuple[float, float] = (0.65, 0.0),
                  friction: float = 0.6) -> SimObject:
        """A static table whose top is at z = ``size[2]`` above the floor."""
        return self.add_object(ObjectSpec("table", (ShapeSpec("box", size),), friction=friction,
                                          xyz=(xyz[0], xyz[1], self.params.floor_z + size[2] / 2), static=True, category="table"))

    def add_object(self, spec: ObjectSpec) -> SimObject:
        if spec.name in self.objects:
            raise WorldError(f"object {spec.name!r} added twice")
        if not spec.shapes:
            raise WorldError(f"object {spec.name!r}: shapes is empty")
        b = self.scene.create_actor_builder()
        mat = sapien.physx.PhysxMaterial(spec.friction, spec.friction, 0.0)
        density = spec.mass / max(spec.volume(), 1e-9)
        for k, s in enumerate(spec.shapes):
            pose = _sapien_pose(xyz_rpy_to_matrix(s.xyz, s.rpy))
            if s.kind == "box":
                if len(s.size) != 3:
                    raise WorldError(f"object {spec.name!r}: shapes[{k}] box needs 3 sizes, got {s.size}")
                b.add_box_collision(pose=pose, half_size=[x / 2 for x in s.size], material=mat, density=density)
                if self.rendering:
                    b.add_box_visual(pose=pose, half_size=[x / 2 for x in s.size])
            elif s.kind == "sphere":
                b.add_sphere_collision(pose=pose, radius=s.size[0], material=mat, density=density)
                if self.rendering:
                    b.add_sphere_visual(pose=pose, radius=s.size[0])
            elif s.kind == "cylinder":
                b.add_cylinder_collision(pose=pose * _TO_X, radius=s.size[0], half_length=s.size[1] / 2, material=mat, density=density)
                if self.rendering:
                    b.add_cylinder_visual(pose=pose * _TO_X, radius=s.size[0], half_length=s.size[1] / 2)
            elif s.kind == "capsule":
                b.add_capsule_collision(pose=pose * _TO_X, radius=s.size[0], half_length=s.size[1] / 2, material=mat, density=density)
                if self.rendering:
                    b.add_capsule_visual(pose=pose * _TO_X, radius=s.size[0], half_length=s.size[1] / 2)
            else:
                raise WorldError(f"object {spec.name!r}: shapes[{k}].kind {s.kind!r} is not box|cylinder|sphere|capsule")
        b.set_initial_pose(_sapien_pose(xyz_rpy_to_matrix(spec.xyz, spec.rpy)))
        entity = b.build_static(name=spec.name) if spec.static else b.build(name=spec.name)
        body = entity.find_component_by_type(sapien.physx.PhysxRigidBaseComponent)
        obj = SimObject(spec, entity, body)
        self.objects[spec.name] = obj
        return obj

    def add_robot(self, robot: str | RobotSpec, name: str | None = None, base: np.ndarray | None = None) -> SimArticulation:
        """Load a registered robot (by name or spec) at ``base`` (default: the spec's placement)."""
        spec = get(robot) if isinstance(robot, str) else robot
        name = name or spec.name
        if name in self.robots:
            raise WorldError(f"robot {name!r} added twice (give a different name=)")
        if base is None:
            base = xyz_rpy_to_matrix(spec.base_xyz, spec.base_rpy)
        art = SimArticulation(self, spec, name, base, group=len(self.robots) + 1)
        self.robots[name] = art
        return art

    def add_screw_bottle(self, spec: ScrewBottleSpec) -> SimScrewBottle:
        """A bottle (fixed in place or free) whose cap turns against the thread's friction (unscrew, §3.3.6)."""
        if spec.name in self.bottles or spec.name in self.objects:
            raise WorldError(f"screw bottle {spec.name!r} added twice")
        if min(spec.body_radius, spec.body_height, spec.neck_radius, spec.neck_height, spec.cap_radius, spec.cap_height,
               spec.cap_mass, spec.density) <= 0:
            raise WorldError(f"screw bottle {spec.name!r}: sizes, cap_mass and density must be positive")
        if spec.thread_friction < 0 or spec.thread_damping < 0 or spec.thread_turns < 0:
            raise WorldError(f"screw bottle {spec.name!r}: thread_friction, thread_damping and thread_turns must be >= 0")
        bottle = SimScrewBottle(self, spec, group=0x8000 + len(self.bottles))
        self.bottles[spec.name] = bottle
        return bottle

    def bottle_poses(self) -> dict[str, np.ndarray]:
        """Ground truth of the screw bottles: each body's pose under its name, its cap's under ``<name>_cap``."""
        out = {}
        for name, b in self.bottles.items():
            out[name], out[f"{name}_cap"] = b.body_pose(), b.cap_pose()
        return out

    def remove_object(self, name: str) -> None:
        obj = self.objects.pop(name)
        # the step's cached contacts would point into the removed body (reading them crashed the process)
        self._contacts = [c for c in self.contacts() if not any(b is obj.body for b in c.bodies)]
        self._by_body_step = -1
        self.scene.remove_entity(obj.entity)

    # -- running -------------------------------------------------------------------------
    def add_hook(self, fn) -> None:
        """Call ``fn(world)`` before every physics step (controllers at physics rate)."""
        self._hooks.append(fn)

    def step(self, n: int = 1) -> None:
        """Advance ``n`` physics steps in lockstep."""
        dt = self.params.timestep
        for _ in range(n):
            for fn in self._hooks:
                fn(self)
            for r in self.robots.values():
                r.pre_step()
            for b in self.bottles.values():
                b.pre_step()
            self.scene.step()
            self.steps += 1
            self.time = self.steps * dt

    def run(self, duration: float) -> None:
        """Step for ``duration`` s; in real-time mode sleep so sim time follows the wall clock."""
        n = max(1, int(round(duration / self.params.timestep)))
        if not self.params.realtime:
            self.step(n)
            return
        if self._t0_wall is None:
            self._t0_wall = time.perf_counter() - self.time
        for _ in range(n):
            self.step()
            ahead = self.time - (time.perf_counter() - self._t0_wall)
            if ahead > 0:
                time.sleep(ahead)

    def contacts(self) -> list:
        """Contacts of the last physics step (queried once per step, shared by every sensor)."""
        if self._contacts_step != self.steps:
            self._contacts = self.scene.get_contacts()
            self._contacts_step = self.steps
        return self._contacts

    def contacts_of(self, bodies: Collection[int]) -> list:
        """The last step's contacts that involve any of ``bodies`` (``id`` of their physx components), in the
        step's order: each hand's sensors read their few contacts, not every contact of the cell."""
        contacts = self.contacts()
        if self._by_body_step != self.steps:
            by: dict[int, list[int]] = {}
            for i, c in enumerate(contacts):
                for b in c.bodies:
                    by.setdefault(id(b), []).append(i)
            self._by_body, self._by_body_step = by, self.steps
        found = {i for b in bodies for i in self._by_body.get(b, ())}
        return [contacts[i] for i in sorted(found)]
