"""Primitive types of the embodiments area, by short name (read by ``contactflow.nodes.registry``)."""

_P = "contactflow.embodiments.primitives"

CATALOG = {
    "robust_grasp": f"{_P}.robust_grasp:RobustGrasp",
    "naive_grasp": f"{_P}.naive_grasp:NaiveGrasp",
    "close_until_force": f"{_P}.close_until_force:CloseUntilForce",
    "close_until_stall": f"{_P}.close_until_stall:CloseUntilStall",
    "transport": f"{_P}.transport:Transport",
    "place": f"{_P}.place:Place",
    "release": f"{_P}.release:Release",
    "slide": f"{_P}.slide:Slide",
    "explore": f"{_P}.explore:Explore",
    "poke": f"{_P}.poke:Poke",
    "unscrew": f"{_P}.unscrew:Unscrew",
    "hold": f"{_P}.hold:Hold",
    "lift": f"{_P}.lift:Lift",
    "push": f"{_P}.push:Push",
    "pull": f"{_P}.pull:Pull",
    "touch": f"{_P}.touch:Touch",
    "move_to": f"{_P}.move_to:MoveTo",
    "detect_objects": f"{_P}.detect_objects:DetectObjects",
    "place_location": f"{_P}.place_location:PlaceLocation",
    "choose_mapped": f"{_P}.choose_mapped:ChooseMapped",
    "wait_event": f"{_P}.wait_event:WaitEvent",
    "watch_prediction": f"{_P}.watch_prediction:WatchPrediction",
    "track": f"{_P}.track:Track",
}
