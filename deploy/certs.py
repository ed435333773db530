"""Test-deployment PKI: a CA and one certificate per host, made with the ``openssl`` CLI.

The venv has no ``cryptography`` package, so the certificates are produced by the system
``openssl`` (3.x). Every host certificate carries the host name as common name (zenoh's
access control matches it as ``cert_common_names``) and as DNS name, plus the host's address
and loopback as IP names, and is valid for both server and client use (mTLS).
"""

from __future__ import annotations

import secrets
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

DAYS = 825  # validity of test certificates


class CertError(RuntimeError):
    """openssl is missing or failed; the message carries its output."""


@dataclass(frozen=True)
class HostCert:
    name: str
    cert: Path
    key: Path


def _openssl(*args: str, cwd: Path) -> None:
    exe = shutil.which("openssl")
    if exe is None:
        raise CertError("the openssl command is not installed (apt-get install openssl)")
    proc = subprocess.run([exe, *args], cwd=cwd, capture_output=True, text=True, timeout=60)
    if proc.returncode != 0:
        raise CertError(f"openssl {' '.join(args[:2])} failed: {proc.stderr.strip()[-400:]}")


def _is_ip(text: str) -> bool:
    parts = text.split(".")
    return len(parts) == 4 and all(p.isdigit() and 0 <= int(p) <= 255 for p in parts)


def make_ca(out: Path, name: str) -> tuple[Path, Path]:
    """A self-signed CA (``ca.pem``, ``ca.key``) in ``out``; an existing one is kept."""
    out.mkdir(parents=True, exist_ok=True)
    ca, key = out / "ca.pem", out / "ca.key"
    if ca.exists() and key.exists():
        return ca, key
    _openssl("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
             "-keyout", key.name, "-out", ca.name, "-days", str(DAYS), "-subj", f"/CN={name}",
             "-addext", "basicConstraints=critical,CA:TRUE", "-addext", "keyUsage=critical,keyCertSign,cRLSign",
             cwd=out)
    key.chmod(0o600)
    return ca, key


def make_host_cert(out: Path, name: str, addresses: list[str]) -> HostCert:
    """``<name>.pem`` / ``<name>.key`` signed by the CA in ``out`` (CN = host name)."""
    ca, ca_key = out / "ca.pem", out / "ca.key"
    if not ca.exists():
        raise CertError(f"{out}: no CA; run make_ca first")
    sans = [f"DNS:{name}", "DNS:localhost", "IP:127.0.0.1"]
    sans += [f"IP:{a}" if _is_ip(a) else f"DNS:{a}" for a in addresses if a not in ("127.0.0.1", "localhost")]
    ext = out / f"{name}.ext"
    ext.write_text(
        "basicConstraints=CA:FALSE\n"
        "keyUsage=critical,digitalSignature,keyEncipherment\n"
        "extendedKeyUsage=serverAuth,clientAuth\n"
        f"subjectAltName={','.join(dict.fromkeys(sans))}\n"
    )
    cert, key, csr = out / f"{name}.pem", out / f"{name}.key", out / f"{name}.csr"
    _openssl("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
             "-keyout", key.name, "-out", csr.name, "-subj", f"/CN={name}", cwd=out)
    _openssl("x509", "-req", "-in", csr.name, "-CA", ca.name, "-CAkey", ca_key.name, "-CAcreateserial",
             "-out", cert.name, "-days", str(DAYS), "-extfile", ext.name, cwd=out)
    key.chmod(0o600)
    csr.unlink()
    ext.unlink()
    return HostCert(name, cert, key)


def make_passwords(path: Path, users: list[str]) -> dict[str, str]:
    """A zenoh usrpwd dictionary (``user:password`` lines); existing entries are kept."""
    known: dict[str, str] = {}
    if path.exists():
        for line in path.read_text().splitlines():
            user, sep, pw = line.partition(":")
            if sep:
                known[user] = pw
    for u in users:
        known.setdefault(u, secrets.token_urlsafe(18))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(f"{u}:{p}\n" for u, p in known.items()))
    path.chmod(0o600)
    return known
