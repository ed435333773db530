"""Module types of the abstraction area, by short name."""

CATALOG = {
    "broker": "contactflow.abstraction.broker_module:BrokerModule",
    "robot_agent": "contactflow.abstraction.agent_module:RobotAgentModule",
}
