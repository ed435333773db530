"""Sensors derived from the physics: wrist F/T, tactile arrays, finger encoders, RGBD camera, ground truth."""
