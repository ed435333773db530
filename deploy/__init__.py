"""Deployment: manifests, launcher, CLI and zenoh configurations."""
