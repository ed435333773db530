"""Scene files of the cells a world module builds (``embodiments/scene_file.py``)."""
