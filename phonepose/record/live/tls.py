"""The self-signed TLS certificate of ``record live`` (WebXR and DeviceMotion need a secure origin).

Generated with ``cryptography`` on first use (EC P-256, one year, serverAuth, the names and IP
addresses the phone may use in its subject alternative names) and stored as ``cert.pem`` /
``key.pem`` (mode 0600) in ``$XDG_CONFIG_HOME/phonepose/tls`` (default ``~/.config/phonepose/tls``)
or ``--tls-dir``. It is reused while it is valid for at least another day and covers every name
asked for; otherwise a new one replaces it (the phone then shows its warning once more). A pair that
cannot be used (a file missing, empty, cut short or not PEM, a key that is not the certificate's)
is replaced too, with a reason the command prints as one warning line. Both files are written to
temporaries and renamed into place (``os.replace``), so an interrupted write leaves either the old
files or a key that does not match its certificate, which the next run replaces.
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
    broken: str = ""     # why the pair found in the folder could not be used ("": none, or only outdated)

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


class _Unusable(Exception):
    """The stored pair cannot be loaded (the message says which file and why)."""


def _load_pair(cert_path: Path, key_path: Path):
    """The stored certificate, checked to load as the server will load it, with the key that matches it;
    None when neither file exists (a first run); :class:`_Unusable` otherwise."""
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    if not cert_path.exists() and not key_path.exists():
        return None
    cert_pem, key_pem = _read(cert_path), _read(key_path)
    try:
        cert = x509.load_pem_x509_certificate(cert_pem)
    except ValueError:
        raise _Unusable(f"{cert_path.name}: not a PEM certificate (cut short or damaged)") from None
    try:
        key = serialization.load_pem_private_key(key_pem, password=None)
    except ValueError:
        raise _Unusable(f"{key_path.name}: not a PEM private key (cut short or damaged)") from None
    except TypeError:
        raise _Unusable(f"{key_path.name}: a key protected by a password") from None
    raw = (serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo)
    if key.public_key().public_bytes(*raw) != cert.public_key().public_bytes(*raw):
        raise _Unusable(f"{key_path.name} is not the key of {cert_path.name}")
    try:   # what ssl_context() does: anything OpenSSL refuses here would stop every later run
        ssl.create_default_context(ssl.Purpose.CLIENT_AUTH).load_cert_chain(str(cert_path), str(key_path))
    except (OSError, ssl.SSLError) as exc:
        raise _Unusable(f"OpenSSL cannot load the pair ({_why(exc)})") from None
    return cert


def _read(path: Path) -> bytes:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise _Unusable(f"{path.name}: {exc.strerror or exc}") from None
    if not data:
        raise _Unusable(f"{path.name}: empty")
    return data


def _why(exc: Exception) -> str:
    text = str(exc).strip().splitlines()
    return text[0][:120] if text else type(exc).__name__


def _covers(cert, hosts) -> bool:
    """Valid for at least another day, every host name and IP address in its subject alternative names."""
    from cryptography import x509

    if cert.not_valid_after_utc < dt.datetime.now(dt.UTC) + dt.timedelta(days=1):
        return False
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return False
    names, ips = _split(hosts)
    have_names = set(san.get_values_for_type(x509.DNSName))
    have_ips = set(san.get_values_for_type(x509.IPAddress))
    return set(names) <= have_names and set(ips) <= have_ips


def _write_atomic(path: Path, data: bytes, mode: int) -> None:
    """``data`` in ``path`` whole or not at all: a temporary in the same folder, then ``os.replace``."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


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
    broken = ""
    try:
        cert = _load_pair(cert_path, key_path)
    except _Unusable as exc:
        cert, broken = None, str(exc)
    if cert is not None and _covers(cert, hosts):
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
        # key first: a run cut between the two renames finds a key that is not its certificate's and replaces both
        _write_atomic(key_path, key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                                  serialization.NoEncryption()), 0o600)
        _write_atomic(cert_path, cert.public_bytes(serialization.Encoding.PEM), 0o644)
    except OSError as exc:
        raise OutputError(f"cannot write the TLS certificate to {d}: {exc.strerror or exc} (choose another "
                          "directory with {tls_dir})", parameter="tls_dir", value=d) from None
    return Certificate(cert_path, key_path, _fingerprint(cert), created=True, broken=broken)
