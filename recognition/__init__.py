"""Object perception: 3D segmentation pipeline, grasp synthesis and hierarchical recognition (thesis §6.3.3, §6.3.5, ch. 8)."""
