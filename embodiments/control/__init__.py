"""Pure control classes: kinematics, velocity IK, Cartesian and joint control, planning, trajectories."""
