"""Services of the 3D vision pipeline (thesis Fig. 6.5), one per file."""
