"""Deployment manifests shipped with contactflow (the thesis layout is default.yaml)."""
