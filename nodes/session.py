"""Client sessions for tools (CLI, tests, broker clients) joining a site's zenoh network."""

from __future__ import annotations

import os

from contactflow.nodes.transport import ZenohSettings, ZenohTransport

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def tool_settings(connect: list[str] | None = None, listen: list[str] | None = None,
                  config_file: str | None = None) -> ZenohSettings:
    """Peer settings for a tool: endpoints from arguments, else ``CONTACTFLOW_CONNECT``."""
    if not connect:
        env = os.environ.get("CONTACTFLOW_CONNECT", DEFAULT_ENDPOINT)
        connect = [e for e in env.split(",") if e]
    return ZenohSettings(mode="peer", connect=tuple(connect), listen=tuple(listen or ()),
                         config_file=config_file or os.environ.get("CONTACTFLOW_ZENOH_CONFIG"))


def open_tool_session(connect: list[str] | None = None, config_file: str | None = None) -> ZenohTransport:
    """A peer session for a tool, once it has discovered the rest of the mesh."""
    t = ZenohTransport(tool_settings(connect, config_file=config_file)).open()
    t.settle()
    return t


def default_site(site: str | None = None) -> str:
    return site or os.environ.get("CONTACTFLOW_SITE", "default")
