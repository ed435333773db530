"""Small generic modules: a signal source, filters and a threshold watcher (demo pipelines)."""
