"""HTTPS for a console other machines reach: the lab's certificate, or one of our own.

Why (issue 44): a console bound to the lab's network carries every person's token in its
links and pages; over plain http anyone on the way reads them. So a console that is not
on loopback serves https by default: with the lab's certificate when the config names it
(``certfile``/``keyfile``), else with a self-signed one made once on this machine and
kept (its key 0600) so that its fingerprint stays the same from trial to trial. The
fingerprint is printed with the links; a colleague compares it with what her browser
shows before she accepts the warning once. Loopback stays plain http (an SSH tunnel, a
reverse proxy that terminates TLS in front of it), and ``tls = "off"`` says so for any
address.

The certificate: EC P-256, valid 825 days (what browsers accept for a leaf), its
subject alternative names this machine's name, its fully qualified name, ``localhost``
and the address bound when it is one; ``cryptography`` makes it (the ``web`` extra).
"""

from __future__ import annotations

import datetime
import hashlib
import ipaddress
import os
import socket
from pathlib import Path
from typing import Final

from testbed.core.addresses import is_loopback_host

__all__ = ["DEFAULT_DIR", "certificate_fingerprint", "console_certificate", "self_signed"]

DEFAULT_DIR: Final = Path("~/.local/state/fleet-testbed/web-tls")
"""Where the self-signed certificate and its key are kept (``$XDG_STATE_HOME`` first)."""
VALID_DAYS: Final = 825


def default_dir() -> Path:
    state = os.environ.get("XDG_STATE_HOME")
    return Path(state) / "fleet-testbed" / "web-tls" if state else DEFAULT_DIR.expanduser()


def console_certificate(host: str, tls: str, folder: Path | None, certfile: str | None,
                        keyfile: str | None) -> tuple[str | None, str | None, bool]:
    """(certfile, keyfile, made here) the console serves with: the lab's when given; off
    loopback with ``tls = "auto"``, this machine's self-signed one; else none (http)."""
    if (certfile is None) != (keyfile is None):
        raise ValueError("humans.web: give both certfile and keyfile, or neither")
    if certfile is None and tls == "auto" and not is_loopback_host(host):
        made, key = self_signed(host, folder)
        return made, key, True
    return certfile, keyfile, False


def certificate_fingerprint(certfile: str | os.PathLike[str]) -> str:
    """The certificate's SHA-256 fingerprint as browsers show it (``AB:CD:...``)."""
    from cryptography import x509
    from cryptography.hazmat.primitives.serialization import Encoding

    cert = x509.load_pem_x509_certificate(Path(certfile).read_bytes())
    digest = hashlib.sha256(cert.public_bytes(Encoding.DER)).hexdigest().upper()
    return ":".join(digest[i:i + 2] for i in range(0, len(digest), 2))


def self_signed(host: str, folder: Path | None = None) -> tuple[str, str]:
    """(certfile, keyfile) of this machine's self-signed console certificate, made the
    first time (the key created mode 0600) and kept in ``folder``."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    folder = folder or default_dir()
    cert_path, key_path = folder / "console-cert.pem", folder / "console-key.pem"
    if cert_path.exists() and key_path.exists():
        return str(cert_path), str(key_path)
    folder.mkdir(parents=True, exist_ok=True)
    key = ec.generate_private_key(ec.SECP256R1())
    names: list[x509.GeneralName] = [x509.DNSName(n) for n in
                                     dict.fromkeys((socket.gethostname(), socket.getfqdn(),
                                                    "localhost"))]
    try:
        names.append(x509.IPAddress(ipaddress.ip_address(host)))
    except ValueError:
        names.append(x509.DNSName(host))
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, socket.getfqdn()[:64]),
                         x509.NameAttribute(NameOID.ORGANIZATION_NAME, "fleet-testbed console")])
    now = datetime.datetime.now(datetime.UTC)
    cert = (x509.CertificateBuilder().subject_name(subject).issuer_name(subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=VALID_DAYS))
            .add_extension(x509.SubjectAlternativeName(names), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .sign(key, hashes.SHA256()))
    fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(key.private_bytes(serialization.Encoding.PEM,
                                  serialization.PrivateFormat.PKCS8,
                                  serialization.NoEncryption()))
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return str(cert_path), str(key_path)
