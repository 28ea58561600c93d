"""The self-signed TLS certificate of ``record live`` (WebXR and DeviceMotion need a secure origin).

Generated with ``cryptography`` on first use (EC P-256, one year, serverAuth, the names and IP
addresses the phone may use in its subject alternative names) and stored as ``cert.pem`` /
``key.pem`` (mode 0600) in ``$XDG_CONFIG_HOME/phonepose/tls`` (default ``~/.config/phonepose/tls``)
or ``--tls-dir``. It is reused while it is valid for at least another day and covers every name
asked for; otherwise a new one replaces it (the phone then shows its warning once more).
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
import ssl
from dataclasses import dataclass
from pathlib import Path

from phonepose.errors import OutputError

CERT_NAME = "cert.pem"
KEY_NAME = "key.pem"
VALID_DAYS = 365


@dataclass(frozen=True)
class Certificate:
    cert_path: Path
    key_path: Path
    sha256: str          # fingerprint, AA:BB:..., what the phone's warning page shows
    created: bool        # generated now (False: reused)

    def ssl_context(self) -> ssl.SSLContext:
        ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        ctx.load_cert_chain(str(self.cert_path), str(self.key_path))
        return ctx


def default_tls_dir() -> Path:
    base = os.environ.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    return Path(base) / "phonepose" / "tls"


def _split(hosts) -> tuple[list[str], list[ipaddress.IPv4Address | ipaddress.IPv6Address]]:
    names: list[str] = []
    ips: list[ipaddress.IPv4Address | ipaddress.IPv6Address] = []
    for h in hosts:
        try:
            ips.append(ipaddress.ip_address(h))
        except ValueError:
            names.append(h)
    return sorted(set(names)), sorted(set(ips), key=lambda a: (a.version, int(a)))


def _fingerprint(cert) -> str:
    from cryptography.hazmat.primitives import hashes

    return cert.fingerprint(hashes.SHA256()).hex(":").upper()


def _reusable(cert_path: Path, key_path: Path, hosts) -> object | None:
    from cryptography import x509

    try:
        cert = x509.load_pem_x509_certificate(cert_path.read_bytes())
        key_path.stat()
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except (OSError, ValueError, x509.ExtensionNotFound):
        return None
    if cert.not_valid_after_utc < dt.datetime.now(dt.UTC) + dt.timedelta(days=1):
        return None
    names, ips = _split(hosts)
    have_names = set(san.get_values_for_type(x509.DNSName))
    have_ips = set(san.get_values_for_type(x509.IPAddress))
    if not set(names) <= have_names or not set(ips) <= have_ips:
        return None
    return cert


def ensure_certificate(tls_dir: str | os.PathLike | None, hosts) -> Certificate:
    """The certificate in ``tls_dir`` (default :func:`default_tls_dir`), made if missing, expiring or
    not covering ``hosts`` (host names and IP addresses)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    d = Path(tls_dir) if tls_dir is not None else default_tls_dir()
    cert_path, key_path = d / CERT_NAME, d / KEY_NAME
    hosts = list(hosts)
    cert = _reusable(cert_path, key_path, hosts)
    if cert is not None:
        return Certificate(cert_path, key_path, _fingerprint(cert), created=False)
    names, ips = _split(hosts)
    key = ec.generate_private_key(ec.SECP256R1())
    now = dt.datetime.now(dt.UTC)
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "phonepose record live (self-signed)")])
    san: list[x509.GeneralName] = [x509.DNSName(n) for n in names]
    san += [x509.IPAddress(ip) for ip in ips]
    cert = (x509.CertificateBuilder()
            .subject_name(subject).issuer_name(subject)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=VALID_DAYS))
            .add_extension(x509.SubjectAlternativeName(san), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
            .sign(key, hashes.SHA256()))
    try:
        d.mkdir(parents=True, exist_ok=True)
        fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                      serialization.NoEncryption()))
        cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    except OSError as exc:
        raise OutputError(f"cannot write the TLS certificate to {d}: {exc.strerror or exc} (choose another "
                          f"directory with --tls-dir)") from None
    return Certificate(cert_path, key_path, _fingerprint(cert), created=True)
