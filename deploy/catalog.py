"""Module types of the deployment area, by short name."""

CATALOG = {
    "foxglove_view": "contactflow.deploy.view_module:FoxgloveView",
}
