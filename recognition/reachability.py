"""Reachability of hand poses by one arm of a registered embodiment (pinocchio IK), for the grasp filters."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


class ArmReach:
    """An :data:`~contactflow.recognition.grasp_synthesis.IkFn` for arm ``arm`` of robot ``robot``.

    The robot's kinematic model (its URDF, placed at ``base``, default the registry's
    placement) gets its own pinocchio model, so solving never disturbs a running
    controller's state. The solver is the damped least-squares IK of the embodiments'
    planner, seeded at ``seed`` (default: the arm's home pose) with random restarts; a
    pose counts as reachable when the arm's controlled frame gets within ``tol`` of it
    and, with ``obstacles`` (planning ``Obstacle`` records: the cell's fixtures), when that
    solution keeps the robot clear of them and of its other parts, as the planner's goal
    must (a side grasp low beside a short object puts the wrist and the lowest finger in the table).
    The model is loaded on the first call (constructors do no I/O).
    """

    def __init__(self, robot: str, arm: str, base: np.ndarray | None = None, restarts: int = 4,
                 iters: int = 200, tol: float = 1e-3, where: str = "reachability", obstacles: Sequence = ()) -> None:
        self.robot, self.arm_name, self.where = robot, arm, where
        self.base = None if base is None else np.asarray(base, dtype=np.float64)
        self.restarts, self.iters, self.tol = restarts, iters, tol
        self.obstacles = list(obstacles)
        self.kin = None
        self.seed: np.ndarray | None = None
        self._valid = None

    def load(self) -> ArmReach:
        """Build the model; raises ValueError naming ``where`` for an unknown robot or arm."""
        from contactflow.embodiments import registry
        from contactflow.embodiments.control.kinematics import Kinematics
        from contactflow.embodiments.transforms import xyz_rpy_to_matrix

        try:
            spec = registry.get(self.robot)
            self.arm = spec.arm(self.arm_name)
        except KeyError as exc:
            raise ValueError(f"{self.where}: {exc}") from None
        base = self.base if self.base is not None else xyz_rpy_to_matrix(spec.base_xyz, spec.base_rpy)
        self.kin = Kinematics(spec.urdf(), base)
        if self.obstacles:
            from contactflow.embodiments.control.planning import CoalChecker

            self._valid = CoalChecker(self.kin, str(spec.urdf()), self.obstacles, parts=spec.collision_groups).valid
        q = self.kin.q.copy()
        q[self.kin.q_index(self.arm.joints)] = self.arm.home
        self.seed = q
        return self

    def set_seed(self, q_full: np.ndarray) -> None:
        """Start the IK from these joints (the robot's current state, full model vector)."""
        if self.kin is None:
            self.load()
        self.seed = np.asarray(q_full, dtype=np.float64).copy()

    def __call__(self, T: np.ndarray) -> np.ndarray | None:
        from contactflow.embodiments.control.planning import solve_ik

        if self.kin is None:
            self.load()
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"{self.where}: expected a finite 4x4 hand pose, got shape {T.shape}")
        return solve_ik(self.kin, self.arm.joints, self.arm.ee_frame, T, self.seed, self._valid, iters=self.iters,
                        restarts=self.restarts, tol=self.tol)
