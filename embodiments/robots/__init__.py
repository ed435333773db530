"""One data module per robot, each defining ``SPEC`` (see ``contactflow.embodiments.registry``)."""
