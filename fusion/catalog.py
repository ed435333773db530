"""Module types of the fusion area, by short name (see ``contactflow.nodes.registry``)."""

CATALOG = {
    "contact_fusion": "contactflow.fusion.service:ContactFusion",
    "cell_fusion": "contactflow.fusion.cell:CellFusion",
    "contact_cues": "contactflow.fusion.cues:ContactCues",
    "tactile_hypotheses": "contactflow.fusion.generators.tactile:TactileGenerator",
    "force_torque_hypotheses": "contactflow.fusion.generators.force_torque:ForceTorqueGenerator",
    "range_hypotheses": "contactflow.fusion.generators.range:RangeHypothesesGenerator",
    "finger_pose_hypotheses": "contactflow.fusion.generators.finger:FingerPoseHypothesesGenerator",
    "motion_support_hypotheses": "contactflow.fusion.generators.motion:MotionSupportHypothesesGenerator",
    "simulator_support_hypotheses": "contactflow.fusion.generators.simulator:SimulatorSupportGenerator",
    "null_hypotheses": "contactflow.fusion.generators.null:NullHypothesesGenerator",
}
