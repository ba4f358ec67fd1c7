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
                        matches
    zenoh/acl.json5     Zenoh access control for the fleet: every vehicle may subscribe to
                        mmatch/v1/**, and publish only under mmatch/v1/<its id>/**; a router
                        may relay everything (a vehicle peer's zenoh.config_file)
    zenoh/router.json5  a router with mutual TLS and that access control
                        (`mmatch router --config`, or zenohd -c)

Copy to a vehicle only its own <id>.key, tls/<id>.pem, tls/<id>.key.pem, and trust.toml and
tls/ca.pem.
"""

from __future__ import annotations

import datetime
import ipaddress
import json
import os
from pathlib import Path

from mmatch.edge import auth
from mmatch.edge.keys import PREFIX, _check_vehicle
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
        names = sorted(set(vehicles) | set(trust))
        done += make_tls(out / "tls", names, routers=routers, days=days)
        done += write_zenoh_configs(out, names, routers)
    return done


def access_control(vehicles: list[str], routers: list[str] = ()) -> dict:
    """Zenoh's access_control block (zenoh 1.x): deny by default; every fleet member may
    declare subscribers and receive samples under mmatch/v1/**; a vehicle may put only under
    mmatch/v1/<its id>/**; a router (it forwards other vehicles' samples) under mmatch/v1/**.
    Subjects are matched by the TLS certificate's common name."""
    everything = [f"{PREFIX}/**"]
    rules = [
        {"id": "subscribe", "messages": ["declare_subscriber"], "flows": ["ingress", "egress"],
         "permission": "allow", "key_exprs": everything},
        {"id": "deliver", "messages": ["put"], "flows": ["egress"], "permission": "allow",
         "key_exprs": everything},
        {"id": "relay", "messages": ["put"], "flows": ["ingress"], "permission": "allow",
         "key_exprs": everything},
    ]
    subjects = [{"id": f"vehicle {v}", "cert_common_names": [v]} for v in vehicles]
    subjects += [{"id": f"router {r}", "cert_common_names": [r]} for r in routers]
    policies = [{"id": "fleet", "rules": ["subscribe", "deliver"], "subjects": [s["id"] for s in subjects]}]
    for v in vehicles:
        rules.append({"id": f"publish {v}", "messages": ["put"], "flows": ["ingress"],
                      "permission": "allow", "key_exprs": [f"{PREFIX}/{v}/**"]})
        policies.append({"id": f"own keys {v}", "rules": [f"publish {v}"], "subjects": [f"vehicle {v}"]})
    if routers:
        policies.append({"id": "routers relay", "rules": ["relay"],
                         "subjects": [f"router {r}" for r in routers]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def write_zenoh_configs(out: Path, vehicles: list[str], routers: list[str]) -> list[str]:
    """zenoh/acl.json5 (access control only) and zenoh/router.json5 (a TLS router with it)."""
    folder = out / "zenoh"
    folder.mkdir(parents=True, exist_ok=True)
    acl = access_control(vehicles, routers)
    (folder / "acl.json5").write_text(
        "// Zenoh access control of this fleet (`mmatch keys`): a vehicle publishes only under its\n"
        "// own key expressions. Use as zenoh.config_file of a vehicle peer.\n"
        + json.dumps({"access_control": acl}, indent=2) + "\n")
    tls = (out / "tls").resolve()
    name = routers[0] if routers else "router"
    router = {
        "mode": "router",
        "listen": {"endpoints": [f"tls/{name}:7447"]},
        "connect": {"endpoints": []},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"shared_memory": {"enabled": False},
                      "link": {"tls": {"root_ca_certificate": str(tls / "ca.pem"), "enable_mtls": True,
                                       "listen_certificate": str(tls / f"{name}.pem"),
                                       "listen_private_key": str(tls / f"{name}.key.pem"),
                                       "connect_certificate": str(tls / f"{name}.pem"),
                                       "connect_private_key": str(tls / f"{name}.key.pem")}}},
        "plugins_loading": {"enabled": False},
        "access_control": acl,
    }
    (folder / "router.json5").write_text(
        f"// A fleet router with mutual TLS and access control (`mmatch keys`): "
        f"mmatch router --config {folder / 'router.json5'}\n" + json.dumps(router, indent=2) + "\n")
    return [f"zenoh access control {folder / 'acl.json5'}, router config {folder / 'router.json5'}"]


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
