"""Interface-layer modules: thin shells over a robot backend (SimRobot or a real robot driver)."""
