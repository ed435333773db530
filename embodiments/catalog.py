"""Module types of the embodiments area, by short name (see ``contactflow.nodes.registry``)."""

CATALOG = {
    "world": "contactflow.embodiments.modules.world_module:WorldModule",
    "predictor": "contactflow.embodiments.modules.predictor:Predictor",
    "sim_interface": "contactflow.embodiments.modules.sim_interface:SimInterface",
    "cartesian_controller_left": "contactflow.embodiments.modules.cartesian_service:LeftArmCartesianController",
    "cartesian_controller_right": "contactflow.embodiments.modules.cartesian_service:RightArmCartesianController",
    "cartesian_controller_arm": "contactflow.embodiments.modules.cartesian_service:SingleArmCartesianController",
    "planner_left": "contactflow.embodiments.modules.planner_service:LeftArmPlanner",
    "planner_right": "contactflow.embodiments.modules.planner_service:RightArmPlanner",
    "planner_arm": "contactflow.embodiments.modules.planner_service:SingleArmPlanner",
}
