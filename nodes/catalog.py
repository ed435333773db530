"""Module types of the runtime area, by short name."""

CATALOG = {
    "signal_source": "contactflow.nodes.builtin.signal_source:SignalSource",
    "lowpass": "contactflow.nodes.builtin.lowpass:LowPass",
    "scale": "contactflow.nodes.builtin.scale:Scale",
    "threshold_watch": "contactflow.nodes.builtin.threshold_watch:ThresholdWatch",
    "task": "contactflow.nodes.task_module:TaskModule",
}
