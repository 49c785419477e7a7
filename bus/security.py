"""Secure teams: one certificate authority, a key and certificate per participant, mutual TLS on
every Zenoh link and an access-control policy derived from the team.

A team folder (``ringtrack certs DIR --robots N``) holds ``ca.pem`` (the authority's certificate),
``ca.key`` (its key: only ``ringtrack certs`` needs it), ``<name>.pem`` and ``<name>.key`` for every
participant name of :func:`team_names`, and ``team.json`` (the team size it was made for). Each
certificate's common name is its participant's name (``world``, ``monitor``, ``fusion``, ``router``,
``r<i>``); Zenoh reads it from the remote end of each TLS link and matches it against the
``cert_common_names`` subjects of :func:`access_policy`. Keys are ECDSA P-256, files of keys mode 0600.
"""

from __future__ import annotations

import datetime
import ipaddress
import json
import os
import shutil
import socket
import ssl
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from ringtrack.bus.config import LEASE_S, LOOPBACK_ANY_PORT, BusConfig, BusError
from ringtrack.bus.keys import BROADCAST, FUSION, MONITOR, ROOT, ROUTER, WORLD, robot_index, robot_name

AUTHORITY = "ca"
MANIFEST = "team.json"
VALID_DAYS = 365
LOCAL_NAMES = ("localhost", "127.0.0.1", "::1")  # every certificate is valid for loopback endpoints


class SecurityError(BusError):
    """A team folder, certificate or secure endpoint is unusable; one line naming the file or flag and
    the fix."""


def team_names(robots: int) -> list[str]:
    """Every participant that gets a certificate: world, monitor, fusion centre, router, robots."""
    return [WORLD, MONITOR, FUSION, ROUTER, *(robot_name(robot) for robot in range(robots))]


# ---------------------------------------------------------------------------------------- creating
def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "ringtrack team"),
                      x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def _alternative_names(hosts: tuple[str, ...]) -> x509.SubjectAlternativeName:
    """DNS names and IP addresses a listening participant may be reached at (TLS checks the one in
    the endpoint a peer connects to)."""
    entries: list[x509.GeneralName] = []
    for host in dict.fromkeys((*LOCAL_NAMES, *hosts)):
        try:
            entries.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            entries.append(x509.DNSName(host))
    return x509.SubjectAlternativeName(entries)


def issue(
    authority_key: ec.EllipticCurvePrivateKey,
    authority: x509.Certificate | None,
    common_name: str,
    hosts: tuple[str, ...] = (),
    valid_from: datetime.datetime | None = None,
    valid_days: float = VALID_DAYS,
) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    """A new key and its certificate for ``common_name``, signed by ``authority`` (``None``: a
    self-signed authority, whose key is ``authority_key``); valid ``valid_days`` days from
    ``valid_from`` (default: an hour ago, to allow for clock skew between hosts)."""
    start = valid_from or datetime.datetime.now(datetime.UTC) - datetime.timedelta(hours=1)
    key = authority_key if authority is None else ec.generate_private_key(ec.SECP256R1())
    builder = (
        x509.CertificateBuilder()
        .subject_name(_name(common_name))
        .issuer_name(_name(common_name) if authority is None else authority.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(start + datetime.timedelta(days=valid_days))
        .add_extension(x509.BasicConstraints(ca=authority is None, path_length=None), critical=True)
    )
    if authority is None:
        builder = builder.add_extension(
            x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True, content_commitment=False,
                          key_encipherment=False, data_encipherment=False, key_agreement=False,
                          encipher_only=False, decipher_only=False), critical=True)
    else:
        builder = builder.add_extension(_alternative_names(hosts), critical=False).add_extension(
            x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
    return key, builder.sign(authority_key, hashes.SHA256())


def _write_key(path: Path, key: ec.EllipticCurvePrivateKey) -> None:
    """PKCS#8 PEM, created with mode 0600 (never readable by others, not even for an instant)."""
    data = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())
    descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(descriptor, "wb") as file:
        file.write(data)


def _write_certificate(path: Path, certificate: x509.Certificate) -> None:
    path.write_bytes(certificate.public_bytes(serialization.Encoding.PEM))


def create_team(directory: Path, robots: int, hosts: tuple[str, ...] = (), force: bool = False,
                valid_days: float = VALID_DAYS) -> list[str]:
    """Make ``directory``: an authority and a key and certificate for every name of
    :func:`team_names`, each valid for loopback and ``hosts``. Refuses an existing ``directory``
    unless ``force`` (then it is replaced). Returns the participant names."""
    if robots < 1:
        raise SecurityError(f"--robots {robots}: a team has at least 1 robot")
    if directory.exists():
        if not force:
            raise SecurityError(f"{directory} exists; give another DIR, or --force to replace its certificates")
        if not (directory / MANIFEST).is_file() and any(directory.iterdir()):
            raise SecurityError(f"{directory} is not empty and holds no {MANIFEST}: not a team folder; "
                                "--force replaces only team folders")
        shutil.rmtree(directory)
    directory.mkdir(parents=True, mode=0o700)
    authority_key = ec.generate_private_key(ec.SECP256R1())
    _, authority = issue(authority_key, None, "ringtrack authority", valid_days=valid_days)
    _write_key(directory / f"{AUTHORITY}.key", authority_key)
    _write_certificate(directory / f"{AUTHORITY}.pem", authority)
    names = team_names(robots)
    for name in names:
        key, certificate = issue(authority_key, authority, name, hosts, valid_days=valid_days)
        _write_key(directory / f"{name}.key", key)
        _write_certificate(directory / f"{name}.pem", certificate)
    (directory / MANIFEST).write_text(json.dumps({"robots": robots, "hosts": list(hosts)}) + "\n")
    return names


# ---------------------------------------------------------------------------------------- reading
@dataclass(frozen=True)
class Listed:
    """One certificate file of a team folder as ``ringtrack certs DIR --show`` lists it."""

    file: str
    common_name: str
    expires: datetime.datetime
    hosts: tuple[str, ...]
    key_mode: int | None  # permission bits of the matching key file; None: no key file here


def common_name(certificate: x509.Certificate) -> str:
    names = certificate.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(names[0].value) if names else ""


def _load_certificate(path: Path) -> x509.Certificate:
    try:
        return x509.load_pem_x509_certificate(path.read_bytes())
    except FileNotFoundError:
        raise SecurityError(f"{path} is missing; copy it from the team folder made by ringtrack certs") from None
    except ValueError:
        raise SecurityError(f"{path} is not a PEM certificate; make the team folder again with ringtrack certs") \
            from None


def list_team(directory: Path) -> list[Listed]:
    """Every certificate in ``directory``, the authority first, with its expiry."""
    if not directory.is_dir():
        raise SecurityError(f"{directory} is not a folder; make one with ringtrack certs {directory} --robots N")
    listed = []
    paths = sorted(directory.glob("*.pem"), key=lambda path: (path.stem != AUTHORITY, _order(path.stem)))
    for path in paths:
        certificate = _load_certificate(path)
        key = path.with_suffix(".key")
        try:
            hosts = tuple(str(name.value) for name in certificate.extensions.get_extension_for_class(
                x509.SubjectAlternativeName).value)
        except x509.ExtensionNotFound:
            hosts = ()
        listed.append(Listed(path.name, common_name(certificate), certificate.not_valid_after_utc, hosts,
                             key.stat().st_mode & 0o777 if key.exists() else None))
    return listed


def _order(name: str) -> tuple[int, int, str]:
    index = robot_index(name)
    return (1, index, "") if index is not None else (0, 0, name)


@dataclass(frozen=True)
class Team:
    """A team folder, checked: its authority and the team size it was made for."""

    directory: Path
    robots: int

    @property
    def authority(self) -> Path:
        return self.directory / f"{AUTHORITY}.pem"

    def certificate(self, name: str) -> Path:
        return self.directory / f"{name}.pem"

    def key(self, name: str) -> Path:
        return self.directory / f"{name}.key"

    def check(self, name: str, now: datetime.datetime | None = None) -> None:
        """Raise :class:`SecurityError` unless participant ``name`` can use this folder: its key and
        certificate are here, the certificate names ``name``, was signed by this authority and is
        valid now, and a robot's index is within the team the folder was made for."""
        index = robot_index(name)
        if index is not None and index >= self.robots:
            raise SecurityError(f"--secure {self.directory} was made for a team of {self.robots} robots, not for "
                                f"robot {index}; run ringtrack certs {self.directory} --robots {index + 1} --force "
                                "and copy the folder to every host")
        now = now or datetime.datetime.now(datetime.UTC)
        authority = _load_certificate(self.authority)
        certificate = _load_certificate(self.certificate(name))
        if not self.key(name).is_file():
            raise SecurityError(f"{self.key(name)} is missing; copy {name}'s key from the team folder made by "
                                "ringtrack certs")
        if common_name(certificate) != name:
            raise SecurityError(f"{self.certificate(name)} is the certificate of {common_name(certificate)!r}, not "
                                f"of {name!r}; copy {name}.pem and {name}.key from the team folder of ringtrack certs")
        try:
            certificate.verify_directly_issued_by(authority)
        except (ValueError, TypeError, InvalidSignature):
            raise SecurityError(f"{self.certificate(name)} was not issued by {self.authority}; use the files of one "
                                "team folder") from None
        for path, held in ((self.authority, authority), (self.certificate(name), certificate)):
            if held.not_valid_after_utc <= now:
                raise SecurityError(f"{path} expired on {held.not_valid_after_utc:%Y-%m-%d %H:%M} UTC; make new "
                                    f"certificates: ringtrack certs {self.directory} --robots {self.robots} --force")
            if held.not_valid_before_utc > now:
                raise SecurityError(f"{path} is valid only from {held.not_valid_before_utc:%Y-%m-%d %H:%M} UTC; "
                                    "check this host's clock")


def load_team(directory: Path, flag: str = "--secure") -> Team:
    """The team folder ``directory`` (``--secure DIR``), with the team size it was made for."""
    manifest = directory / MANIFEST
    if not manifest.is_file():
        raise SecurityError(f"{flag} {directory}: no {MANIFEST} there; make the folder with ringtrack certs "
                            f"{directory} --robots N")
    try:
        robots = int(json.loads(manifest.read_text())["robots"])
    except (ValueError, KeyError, TypeError):
        raise SecurityError(f"{manifest} is damaged; make the folder again with ringtrack certs --force") from None
    return Team(directory, robots)


def check_team(directory: Path, names: list[str], robots: int | None = None) -> Team:
    """Load the team folder ``directory`` and check it serves every participant of ``names`` in a team
    of ``robots`` robots (default: the team it was made for)."""
    team = load_team(directory)
    if robots is not None and robots > team.robots:
        raise SecurityError(f"--secure {directory} was made for a team of {team.robots} robots, not {robots}; run "
                            f"ringtrack certs {directory} --robots {robots} --force and copy the folder to every host")
    for name in names:
        team.check(name)
    return team


# ------------------------------------------------------------------------------ Zenoh settings
SECURE_LOOPBACK_ANY_PORT = "tls/127.0.0.1:0"
PROBE_TIMEOUT_S = 3.0
# Messages a remote participant may send us for key expressions it is entitled to (Zenoh 1.x names).
SUBSCRIBING = ["declare_subscriber"]
WATCHING = ["declare_liveliness_subscriber", "liveliness_query"]
EVERY_MESSAGE = ["put", "delete", "declare_subscriber", "query", "declare_queryable", "reply", "liveliness_token",
                 "declare_liveliness_subscriber", "liveliness_query"]


def _pattern(destination: str = "*", source: str = "*", kind: str = "*") -> str:
    """A data key of any run (:meth:`ringtrack.bus.keys.Keys.data` with the run id a wildcard): a
    router serves every run, and a policy must not depend on the run id."""
    return f"{ROOT}/*/{destination}/{source}/{kind}"


def inboxes(name: str) -> list[str]:
    """What participant ``name`` may subscribe to: its own inbox and the broadcast; the monitor
    everything of a run (it tallies every message)."""
    if name == MONITOR:
        return [f"{ROOT}/*/**"]
    shared = [f"{ROOT}/*/{BROADCAST}/**"] if name == FUSION or robot_index(name) is not None else []
    return [f"{ROOT}/*/{name}/**", *shared]


def access_policy(robots: int, routers: bool = False) -> dict[str, object]:
    """The ``access_control`` section every secure peer and router enforces on what it receives.

    Default deny. A subject per participant of a team of ``robots`` robots, matched by the common
    name of the certificate at the far end of the link; each may send only data whose key names it as
    the source (``<prefix>/<destination>/<itself>/<kind>``: robot i its requests, replies, commands,
    range reports, statistics and fault notices; the world its measurements, ticks and End), declare
    liveliness tokens only for its own name, subscribe only to its own inbox and the broadcast (the
    monitor: everything), ask only for a life of its own name and watch everyone's tokens; only the
    world answers life queries (:mod:`bus.lives`). Anything sent out is allowed to the team (each
    receiver checks for itself). A certificate of another authority never gets a link at all. With
    ``routers`` (the policy of a router) another router of the team, which enforces this policy
    itself, may forward anything; peers trust no router: through a router, participants are clients.
    """
    names = [WORLD, MONITOR, FUSION, *(robot_name(robot) for robot in range(robots))]
    rules: list[dict[str, object]] = [
        {"id": "send-to-team", "messages": EVERY_MESSAGE, "flows": ["egress"], "permission": "allow",
         "key_exprs": [f"{ROOT}/**"]},
        {"id": "watch-tokens", "messages": WATCHING, "flows": ["ingress"], "permission": "allow",
         "key_exprs": [f"{ROOT}/*/alive/*", f"{ROOT}/*/ready/*", f"{ROOT}/*/claim/*/*", f"{ROOT}/*/reach/*/*"]},
        {"id": "world-grants-lives", "messages": ["declare_queryable", "reply"], "flows": ["ingress"],
         "permission": "allow", "key_exprs": [f"{ROOT}/*/life/*"]},
    ]
    policies: list[dict[str, object]] = []
    for name in names:
        rules += [
            {"id": f"{name}-sends", "messages": ["put"], "flows": ["ingress"], "permission": "allow",
             "key_exprs": [_pattern(source=name)]},
            {"id": f"{name}-tokens", "messages": ["liveliness_token"], "flows": ["ingress"], "permission": "allow",
             "key_exprs": [f"{ROOT}/*/alive/{name}", f"{ROOT}/*/ready/{name}", f"{ROOT}/*/claim/{name}/*",
                           f"{ROOT}/*/reach/*/{name}"]},
            {"id": f"{name}-subscribes", "messages": SUBSCRIBING, "flows": ["ingress"], "permission": "allow",
             "key_exprs": inboxes(name)},
            {"id": f"{name}-asks-life", "messages": ["query"], "flows": ["ingress"], "permission": "allow",
             "key_exprs": [f"{ROOT}/*/life/{name}"]},
        ]
        own = ["world-grants-lives"] if name == WORLD else []
        policies.append({"id": f"{name}-policy", "subjects": [name],
                         "rules": ["send-to-team", "watch-tokens", f"{name}-sends", f"{name}-tokens",
                                   f"{name}-subscribes", f"{name}-asks-life", *own]})
    if routers:
        rules.append({"id": "router-forwards", "messages": EVERY_MESSAGE, "flows": ["ingress"], "permission": "allow",
                      "key_exprs": [f"{ROOT}/**"]})
        policies.append({"id": "router-policy", "subjects": [ROUTER], "rules": ["send-to-team", "router-forwards"]})
        names = [*names, ROUTER]
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": [{"id": name, "cert_common_names": [name]} for name in names], "policies": policies}


@dataclass(frozen=True)
class Security:
    """How a secure participant joins the bus: the team folder and the size of the team it runs in
    (the robots its access-control policy admits)."""

    team: Team
    robots: int

    def settings(self, name: str, mode: str) -> dict[str, object]:
        """Zenoh settings (``path: value``) for participant ``name`` in ``mode``: mutual TLS with its
        own key and certificate on every link, and for peers and routers the team's access-control
        policy. A client links only to the router it names, which enforces the policy for it."""
        key, certificate = str(self.team.key(name).resolve()), str(self.team.certificate(name).resolve())
        settings: dict[str, object] = {
            "transport/link/tls/root_ca_certificate": str(self.team.authority.resolve()),
            "transport/link/tls/listen_private_key": key,
            "transport/link/tls/listen_certificate": certificate,
            "transport/link/tls/connect_private_key": key,
            "transport/link/tls/connect_certificate": certificate,
            "transport/link/tls/enable_mtls": True,
        }
        if mode != "client":
            settings["access_control"] = access_policy(self.robots, routers=mode == "router")
        return settings

    def check(self, name: str) -> None:
        """Raise :class:`SecurityError` unless participant ``name`` can use the team folder (:meth:`Team.check`)."""
        self.team.check(name)

    def probe(self, name: str, endpoint: str) -> None:
        """Raise :class:`SecurityError` when whatever answers at ``endpoint`` (a ``tls/`` endpoint this
        participant connects to) is not a participant of this team: a plain one, or one whose
        certificate another authority signed. Nobody listening yet is fine (Zenoh keeps trying)."""
        host, _, port = endpoint.removeprefix("tls/").rpartition(":")
        host = host.strip("[]")
        context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
        context.load_verify_locations(self.team.authority)
        context.load_cert_chain(self.team.certificate(name), self.team.key(name))
        try:
            with socket.create_connection((host, int(port)), timeout=PROBE_TIMEOUT_S) as raw, \
                    context.wrap_socket(raw, server_hostname=host):
                return
        except ssl.SSLCertVerificationError as error:
            raise SecurityError(f"--connect {endpoint}: the participant there is not of this team "
                                f"({error.verify_message}); give it the certificates of {self.team.directory}") \
                from None
        except (TimeoutError, ssl.SSLError, ConnectionResetError, BrokenPipeError) as error:
            raise SecurityError(f"--connect {endpoint}: the participant there does not speak TLS "
                                f"({type(error).__name__}): it is a plain one; start it with --secure "
                                f"{self.team.directory} too") from None
        except OSError:
            return  # nobody there (yet): Zenoh retries, as for a plain participant


def secure_config(directory: Path, names: list[str], robots: int | None, mode: str, listen: tuple[str, ...],
                  connect: tuple[str, ...], admin_space: bool = False,
                  lease_ms: int = round(LEASE_S * 1000)) -> BusConfig:
    """The bus of participants ``names`` of a team of ``robots`` robots (None: the team the folder
    was made for) with ``--secure directory``: checked certificates and TLS endpoints (the default
    loopback listener becomes ``tls/127.0.0.1:0``; a ``tcp/`` endpoint is refused)."""
    team = check_team(directory, names, robots)
    listen = tuple(SECURE_LOOPBACK_ANY_PORT if endpoint == LOOPBACK_ANY_PORT else endpoint for endpoint in listen)
    return BusConfig(mode=mode, listen=listen, connect=connect, admin_space=admin_space,  # type: ignore[arg-type]
                     lease_ms=lease_ms, security=Security(team, team.robots if robots is None else robots))
