"""Making a fleet's keys: Ed25519 signing keys + trust file, and a TLS CA with per-vehicle
certificates for Zenoh's mutual TLS (`mmatch keys`).

Layout of a fleet folder (private keys mode 0600, the folder 0700):

    <id>.key            the vehicle's Ed25519 signing key (auth.key_file)
    <id>.key.<n>.old    a key replaced by --rotate, still trusted until --retire
    trust.toml          every vehicle's public keys (auth.trust_file), for every Ego
    tls/ca.pem          the fleet CA certificate (root_ca_certificate of every Zenoh config)
    tls/ca.key          the CA's private key: keep it off the vehicles
    tls/<id>.pem, tls/<id>.key.pem   a vehicle's (or router's) certificate and TLS key;
                        the certificate's common name is the id, which Zenoh's access control
                        matches (cfg/zenoh/)

Copy to a vehicle only its own <id>.key, tls/<id>.pem, tls/<id>.key.pem, and trust.toml and
tls/ca.pem.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from pathlib import Path

from mmatch.edge import auth
from mmatch.edge.keys import _check_vehicle
from mmatch.errors import ConfigError


def _write_private(path: Path, data: bytes) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def _public_of(path: Path, vehicle: str) -> bytes:
    return auth.Signer.from_file(vehicle, path).public_raw


def make_fleet(out: str | Path, vehicles: list[str], *, rotate: list[str] = (), retire: list[str] = (),
               tls: bool = False, routers: list[str] = (), days: int = 365) -> list[str]:
    """Create what is missing in the fleet folder `out`; returns one line per thing done."""
    out = Path(out)
    for v in [*vehicles, *rotate, *retire]:
        _check_vehicle(v)
    out.mkdir(parents=True, exist_ok=True, mode=0o700)
    os.chmod(out, 0o700)
    trust_path = out / "trust.toml"
    trust: dict[str, list[bytes]] = {}
    if trust_path.exists():
        trust = {v: list(ids.values()) for v, ids in auth.read_trust(trust_path).items()}
    done: list[str] = []
    for v in dict.fromkeys([*vehicles, *rotate]):
        key = out / f"{v}.key"
        if v in rotate and key.exists():
            n = 1
            while (out / f"{v}.key.{n}.old").exists():
                n += 1
            os.replace(key, out / f"{v}.key.{n}.old")
            done.append(f"{v}: old key kept as {v}.key.{n}.old (still trusted until --retire {v})")
        if not key.exists():
            auth.generate_key(key)
            done.append(f"{v}: new signing key {key}")
        public = _public_of(key, v)
        if public not in trust.setdefault(v, []):
            trust[v].append(public)
    for v in retire:
        key = out / f"{v}.key"
        if not key.exists():
            raise ConfigError(f"--retire {v}: {key} does not exist")
        trust[v] = [_public_of(key, v)]
        done.append(f"{v}: only key {auth.key_id(trust[v][0]).hex()} trusted now")
    auth.write_trust(trust_path, trust)
    done.append(f"trust file {trust_path}: {len(trust)} vehicle(s)")
    if tls:
        done += make_tls(out / "tls", sorted(set(vehicles) | set(trust)), routers=routers, days=days)
    return done


def make_tls(folder: Path, names: list[str], *, routers: list[str] = (), days: int = 365) -> list[str]:
    """A fleet CA (made once) and a certificate per vehicle and router (made when missing).

    Vehicle certificates carry the id as common name and as DNS name; router certificates
    their DNS name or IP address (what the vehicles connect to) as subject alternative name.
    """
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    done: list[str] = []
    now = datetime.datetime.now(datetime.timezone.utc)
    ca_pem, ca_key_path = folder / "ca.pem", folder / "ca.key"
    pem = serialization.Encoding.PEM
    if ca_pem.exists() and ca_key_path.exists():
        ca_key = serialization.load_pem_private_key(ca_key_path.read_bytes(), password=None)
        ca_cert = x509.load_pem_x509_certificate(ca_pem.read_bytes())
    else:
        ca_key = ec.generate_private_key(ec.SECP256R1())
        name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "mmatch fleet CA")])
        ca_cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name)
                   .public_key(ca_key.public_key()).serial_number(x509.random_serial_number())
                   .not_valid_before(now - datetime.timedelta(minutes=5))
                   .not_valid_after(now + datetime.timedelta(days=10 * days))
                   .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
                   .add_extension(x509.KeyUsage(digital_signature=False, content_commitment=False,
                                                key_encipherment=False, data_encipherment=False,
                                                key_agreement=False, key_cert_sign=True, crl_sign=True,
                                                encipher_only=False, decipher_only=False), critical=True)
                   .add_extension(x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), critical=False)
                   .sign(ca_key, hashes.SHA256()))
        _write_private(ca_key_path, ca_key.private_bytes(pem, serialization.PrivateFormat.PKCS8,
                                                         serialization.NoEncryption()))
        ca_pem.write_bytes(ca_cert.public_bytes(pem))
        done.append(f"fleet CA {ca_pem} (keep {ca_key_path} off the vehicles)")
    for name in [*names, *routers]:
        cert_path, key_path = folder / f"{name}.pem", folder / f"{name}.key.pem"
        if cert_path.exists() and key_path.exists():
            continue
        key = ec.generate_private_key(ec.SECP256R1())
        try:
            san: x509.GeneralName = x509.IPAddress(ipaddress.ip_address(name))
        except ValueError:
            san = x509.DNSName(name)
        cert = (x509.CertificateBuilder()
                .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
                .issuer_name(ca_cert.subject).public_key(key.public_key())
                .serial_number(x509.random_serial_number())
                .not_valid_before(now - datetime.timedelta(minutes=5))
                .not_valid_after(now + datetime.timedelta(days=days))
                .add_extension(x509.SubjectAlternativeName([san]), critical=False)
                .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                      ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
                .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()),
                               critical=False)
                .sign(ca_key, hashes.SHA256()))
        _write_private(key_path, key.private_bytes(pem, serialization.PrivateFormat.PKCS8,
                                                   serialization.NoEncryption()))
        cert_path.write_bytes(cert.public_bytes(pem))
        done.append(f"{name}: TLS certificate {cert_path}")
    return done
