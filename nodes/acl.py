"""The site's access rules as one session sees them: a query they refuse is answered at once, not by a timeout.

A deployment's zenoh settings (``deploy/security.py``) carry one ``access_control`` section
shared by every node. A node enforces it on what it receives (ingress), and a refused query is
dropped there without an answer: the caller would wait for its timeout. Every node has the same
section, so a session can tell beforehand what the others will refuse it, and refuse the query
itself with an error naming the key and the rule.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh


class AccessDenied(PermissionError):
    """The site's access rules refuse this session a message; the text names the key and the identity."""


@dataclass(frozen=True)
class AccessRules:
    """What the other nodes accept from ``identity`` (their ingress rules for its subjects)."""

    identity: str
    allow: dict[str, tuple[str, ...]]  # message kind (query, put, ...) -> key expressions
    deny: dict[str, tuple[str, ...]]

    @classmethod
    def of(cls, section: dict[str, Any], identity: str, by_user: bool) -> AccessRules:
        """The rules of ``section`` for the subject naming ``identity`` (by user name, or certificate name)."""
        by = "usernames" if by_user else "cert_common_names"
        subjects = {s["id"] for s in section.get("subjects", []) if identity in s.get(by, [])}
        rule_ids = {r for p in section.get("policies", []) if subjects & set(p.get("subjects", []))
                    for r in p.get("rules", [])}
        allow: dict[str, list[str]] = {}
        deny: dict[str, list[str]] = {}
        for rule in section.get("rules", []):
            if rule.get("id") not in rule_ids or "ingress" not in rule.get("flows", []):
                continue
            into = deny if rule.get("permission") == "deny" else allow
            for message in rule.get("messages", []):
                into.setdefault(message, []).extend(rule.get("key_exprs", []))
        return cls(identity, {m: tuple(k) for m, k in allow.items()}, {m: tuple(k) for m, k in deny.items()})

    @classmethod
    def load(cls, config_file: str | Path) -> AccessRules | None:
        """The rules of a zenoh JSON settings file with access control, for the identity it logs in as.

        The identity is the file's password user, else the host its certificate is named after
        (``contactflow deploy certs`` names each host's certificate ``<host>.pem``, CN ``<host>``).
        None when the file has no access control, or is JSON5 that plain JSON cannot read.
        """
        try:
            cfg = json.loads(Path(config_file).read_text())
        except (OSError, ValueError):
            return None
        section = cfg.get("access_control") if isinstance(cfg, dict) else None
        if not isinstance(section, dict) or not section.get("enabled"):
            return None
        link = cfg.get("transport", {})
        user = link.get("auth", {}).get("usrpwd", {}).get("user")
        if user:
            return cls.of(section, user, by_user=any("usernames" in s for s in section.get("subjects", [])))
        cert = link.get("link", {}).get("tls", {}).get("connect_certificate")
        return cls.of(section, Path(cert).stem, by_user=False) if cert else None

    @functools.cached_property
    def exprs(self) -> dict[str, zenoh.KeyExpr]:
        """The rules' key expressions, parsed once: a node checks every query it sends."""
        return {r: zenoh.KeyExpr(r) for rules in (*self.allow.values(), *self.deny.values()) for r in rules}

    def check(self, message: str, key: str) -> None:
        """Raise :class:`AccessDenied` unless the other nodes accept ``message`` on ``key`` from this session."""
        k = zenoh.KeyExpr(key)
        exprs = self.exprs
        denied = next((r for r in self.deny.get(message, ()) if exprs[r].intersects(k)), None)
        if denied is not None:
            raise AccessDenied(f"{key}: the site's access rules deny host {self.identity!r} a {message} there "
                               f"(rule {denied})")
        if not any(exprs[r].includes(k) for r in self.allow.get(message, ())):
            raise AccessDenied(f"{key}: the site's access rules do not let host {self.identity!r} {message} it")
