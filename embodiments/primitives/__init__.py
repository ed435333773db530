"""The manipulation primitive vocabulary (thesis ch. 3, §6.3.6) as reactive controllers on a robot facade."""
