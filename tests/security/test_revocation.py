"""Who the router admits, from certificates and the revocation list alone: the common name
that makes each certificate its own, the CRL that `revoke` and `issue --force` write, the
store `export` makes for the Pi, and the one warning per certificate the router leaves out."""
from __future__ import annotations

import datetime as dt
import json
import logging
import shutil

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec

from viena.common.config import load_zenoh_config
from viena.common.keystore import KeyStore, SecurityError, common_name, name_of
from viena.common.secure import secure_router
from viena.keys_cli import main as keys

#: what the Pi runs, as docs/deployment.md exports it
PI = ["router", "gnss0", "gnss1", "razor0", "steering", "estimator", "autopilot", "recorder"]
PEOPLE = {"alice": "pilot", "bob": "observer"}


def run_keys(capsys, store: KeyStore, *args) -> tuple[int, str, str]:
    status = keys(["--keys", str(store.dir), *args])
    out, err = capsys.readouterr()
    return status, out, err


@pytest.fixture
def trusted(tmp_path) -> KeyStore:
    """The store where the CA is kept, with two people."""
    store = KeyStore(tmp_path / "trusted", "elettra")
    store.init()
    for name, role in PEOPLE.items():
        store.issue(role, name)
    return store


def load(path) -> x509.Certificate:
    return x509.load_pem_x509_certificate(path.read_bytes())


def crl_of(store: KeyStore) -> x509.CertificateRevocationList:
    return x509.load_pem_x509_crl(store.crl.read_bytes())


def legacy(store: KeyStore, role: str, name: str) -> None:
    """A certificate as `viena keys` made them before tagged common names: CN = NAME."""
    ca_key = serialization.load_pem_private_key(store.ca_key.read_bytes(), None)
    ca = load(store.ca_cert)
    key = ec.generate_private_key(ec.SECP256R1())
    now = dt.datetime.now(dt.UTC)
    subject = x509.Name([x509.NameAttribute(x509.oid.NameOID.ORGANIZATION_NAME, "viena elettra"),
                         x509.NameAttribute(x509.oid.NameOID.ORGANIZATIONAL_UNIT_NAME, role),
                         x509.NameAttribute(x509.oid.NameOID.COMMON_NAME, name)])
    cert = (x509.CertificateBuilder().subject_name(subject).issuer_name(ca.subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5)).not_valid_after(now + dt.timedelta(days=100))
            .sign(ca_key, hashes.SHA256()))
    (store.dir / f"{name}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    (store.dir / f"{name}.key").write_bytes(key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()))
    (store.dir / f"{name}.key").chmod(0o600)


def acl(store: KeyStore) -> dict:
    conf = load_zenoh_config(mode="router", listen=["tls/127.0.0.1:7447"])
    secure_router(conf, store)
    return json.loads(conf.get_json("access_control"))


# -- the common name ----------------------------------------------------------------------------
def test_a_certificate_is_named_name_dot_the_last_16_hex_digits_of_its_serial(trusted):
    alice = trusted.identity("alice")
    cert = load(alice.cert)
    cn = cert.subject.get_attributes_for_oid(x509.oid.NameOID.COMMON_NAME)[0].value
    ou = cert.subject.get_attributes_for_oid(x509.oid.NameOID.ORGANIZATIONAL_UNIT_NAME)[0].value
    assert cn == alice.common_name == f"alice.{cert.serial_number % 2**64:016x}" and ou == "pilot"
    assert (alice.name, alice.role, alice.serial) == ("alice", "pilot", cert.serial_number)


@pytest.mark.parametrize("cn, serial, name", [
    ("alice.00000000000000ff", 0xff, "alice"),
    ("alice.00000000000000ff", (7 << 64) | 0xff, "alice"),        # the last 16 digits only
    ("gnss0.00000000000000ff", 0xff, "gnss0"),
    ("alice", 0xff, "alice"),                                     # made before tags
    ("alice.00000000000000fe", 0xff, None),                       # another certificate's tag
    ("alice.ff", 0xff, None),
    ("alice.", 0xff, None),
    ("Alice.00000000000000ff", 0xff, None),
    ("viena elettra CA", 0xff, None),
    ("", 0xff, None),
])
def test_the_name_is_what_comes_before_the_dot(cn, serial, name):
    assert name_of(cn, serial) == name
    if name is not None and "." in cn:
        assert common_name(name, serial) == cn


def test_every_certificate_of_a_name_has_its_own_common_name(trusted):
    first = trusted.identity("alice")
    second = trusted.issue("pilot", "alice", force=True)
    assert second.name == first.name == "alice" and second.common_name != first.common_name


def test_a_certificate_made_before_tags_is_read_as_its_name(trusted, capsys):
    legacy(trusted, "observer", "dave")
    dave = trusted.identity("dave")
    assert (dave.name, dave.common_name, dave.legacy) == ("dave", "dave", True)
    subjects = {s["id"]: s["cert_common_names"] for s in acl(trusted)["subjects"]}
    assert subjects["dave"] == ["dave"]
    _, out, _ = run_keys(capsys, trusted, "list")
    line = next(row for row in out.splitlines() if row.startswith("dave"))
    assert "re-issue (`viena keys issue observer dave --force`)" in line


# -- access control from certificates ---------------------------------------------------------------
def test_access_control_lists_each_names_current_common_name_whatever_keys_are_there(trusted):
    for name in PEOPLE:
        (trusted.dir / f"{name}.key").unlink()          # people keep their keys on their laptops
    block = acl(trusted)
    subjects = {s["id"]: s["cert_common_names"] for s in block["subjects"]}
    for name in [*PEOPLE, "gnss0", "steering", "observer"]:
        assert subjects[name] == [trusted.certificate(trusted.dir / f"{name}.pem").common_name]
        assert subjects[name][0].startswith(f"{name}.")
    assert "router" not in subjects
    rules = {r["id"]: r["key_exprs"] for r in block["rules"]}
    assert rules["gnss0/publish"] == ["viena/elettra/gnss/gnss0/**"]            # {name} is the name
    assert rules["alice/token"] == ["viena/elettra/alive/pilot/alice"]
    policies = {p["id"]: p for p in block["policies"]}
    assert "alice/command" in policies["alice"]["rules"] and "bob/command" not in policies["bob"]["rules"]
    assert block["default_permission"] == "deny"


def test_the_router_leaves_out_each_unusable_certificate_with_one_warning(trusted, tmp_path, caplog, monkeypatch):
    import viena.common.keystore as keystore

    other = KeyStore(tmp_path / "other", "elettra")
    other.init()
    shutil.copy(other.dir / "pilot.pem", trusted.dir / "pilot.pem")                    # another CA's
    long_ago = dt.datetime.now(dt.UTC) - dt.timedelta(days=40)
    trusted.issue("pilot", "old", days=10, valid_from=long_ago)                         # expired
    monkeypatch.setitem(keystore.ROLES, "wizard", keystore.ROLES["observer"])
    trusted.issue("wizard", "merlin")                                                   # unknown role
    monkeypatch.delitem(keystore.ROLES, "wizard")
    (trusted.dir / "junk.pem").write_text("hello\n")                                   # unreadable
    shutil.copy(trusted.dir / "bob.pem", trusted.dir / "robert.pem")                   # misnamed
    shutil.copy(trusted.dir / "bob.pem", tmp_path / "bob.pem")
    trusted.revoke("bob")
    shutil.copy(tmp_path / "bob.pem", trusted.dir / "bob.pem")                         # revoked
    caplog.set_level(logging.INFO)
    conf = load_zenoh_config(mode="router", listen=["tls/127.0.0.1:7447"])
    admitted = {i.name: i.role for i in secure_router(conf, trusted)}
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert {r.name for r in warnings} == {"viena.router"}
    why = {w.getMessage().split(": ", 2)[1].rsplit("/", 1)[1]: w.getMessage().split(": ", 2)[2]
           for w in warnings}
    assert sorted(why) == ["bob.pem", "junk.pem", "merlin.pem", "old.pem", "pilot.pem", "robert.pem"]
    assert why["pilot.pem"].startswith("not signed by this car's CA")
    assert why["old.pem"].startswith("expired on")
    assert why["merlin.pem"].startswith("unknown role 'wizard'")
    assert why["junk.pem"] == "not a PEM certificate"
    assert why["robert.pem"] == "certificate is for 'bob', not 'robert'"
    assert why["bob.pem"].startswith("revoked on") and "(unspecified)" in why["bob.pem"]
    assert admitted["alice"] == "pilot" and admitted["observer"] == "observer"
    assert not {"pilot", "old", "merlin", "bob", "robert", "junk", "router"} & set(admitted)


def test_a_revocation_list_the_ca_did_not_sign_stops_the_router(trusted, tmp_path):
    other = KeyStore(tmp_path / "other", "elettra")
    other.init()
    other.issue("observer", "x")
    other.revoke("x")
    shutil.copy(other.crl, trusted.crl)
    with pytest.raises(SecurityError, match=r"crl\.pem: not signed by this car's CA .*viena keys export"):
        trusted.client_certificates()
    trusted.crl.write_text("not a list\n")
    with pytest.raises(SecurityError, match=r"crl\.pem: not a PEM revocation list"):
        secure_router(load_zenoh_config(mode="router", listen=["tls/127.0.0.1:7447"]), trusted)


# -- revocation ---------------------------------------------------------------------------------------
def test_revoke_puts_the_serial_on_a_crl_signed_by_the_ca(trusted, capsys):
    bob = trusted.identity("bob")
    status, out, err = run_keys(capsys, trusted, "revoke", "bob", "--reason", "key-compromise")
    assert status == 0, err
    assert f"revoked 'bob' (serial {bob.serial:x}, key-compromise)" in out and "next start" in out
    crl, ca = crl_of(trusted), load(trusted.ca_cert)
    assert crl.issuer == ca.subject and crl.is_signature_valid(ca.public_key())
    entry = crl.get_revoked_certificate_by_serial_number(bob.serial)
    assert entry.extensions.get_extension_for_class(x509.CRLReason).value.reason == x509.ReasonFlags.key_compromise
    assert not (trusted.dir / "bob.key").exists() and not bob.cert.exists()
    assert (trusted.revoked_dir / f"bob.{bob.serial:x}.pem").read_bytes() == load(
        trusted.revoked_dir / f"bob.{bob.serial:x}.pem").public_bytes(serialization.Encoding.PEM)
    assert "bob" not in [i.name for i in trusted.client_identities()]
    status, _, err = run_keys(capsys, trusted, "revoke", "bob")
    assert status == 2 and "'bob' is revoked already" in err and err.count("\n") == 1


def test_a_revoked_certificate_is_refused_wherever_it_turns_up(trusted, tmp_path):
    shutil.copy(trusted.dir / "bob.pem", tmp_path / "bob.pem")
    shutil.copy(trusted.dir / "bob.key", tmp_path / "bob.key")
    trusted.revoke("bob")
    for suffix in (".pem", ".key"):
        shutil.copy(tmp_path / f"bob{suffix}", trusted.dir / f"bob{suffix}")
    with pytest.raises(SecurityError, match=r"bob\.pem: revoked on .* UTC \(unspecified\)"):
        trusted.identity("bob")                     # a process presenting it stops at once


def test_reissuing_a_name_revokes_its_old_certificate(trusted, capsys):
    old = trusted.identity("alice")
    status, out, _ = run_keys(capsys, trusted, "issue", "pilot", "alice", "--force")
    assert status == 0 and f"revoked its previous certificate (serial {old.serial:x})" in out
    entry = crl_of(trusted).get_revoked_certificate_by_serial_number(old.serial)
    assert entry.extensions.get_extension_for_class(x509.CRLReason).value.reason == x509.ReasonFlags.superseded
    new = trusted.identity("alice")
    assert new.serial != old.serial and crl_of(trusted).get_revoked_certificate_by_serial_number(new.serial) is None
    assert [i.common_name for i in trusted.client_identities() if i.name == "alice"] == [new.common_name]


def test_list_shows_what_is_revoked(trusted, capsys):
    alice, bob = trusted.identity("alice"), trusted.identity("bob")
    trusted.issue("pilot", "alice", force=True)
    trusted.revoke("bob", "privilege-withdrawn")
    status, out, _ = run_keys(capsys, trusted, "list")
    assert status == 0
    revoked = out[out.index("\nrevoked ("):].splitlines()
    assert "2): the router refuses these from its next start" in revoked[1]
    today = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d")
    rows = {row.split()[0]: row.split() for row in revoked[3:]}
    assert rows["alice"][1:3] == [f"{alice.serial:x}", today] and rows["alice"][-1] == "superseded"
    assert rows["bob"][1:3] == [f"{bob.serial:x}", today] and rows["bob"][-1] == "privilege-withdrawn"


def test_revocation_needs_the_ca_key(trusted, tmp_path, capsys):
    pi = KeyStore(tmp_path / "pi", "elettra")
    trusted.export(PI, pi)
    status, _, err = run_keys(capsys, pi, "revoke", "alice")
    assert status == 2 and "ca.key: missing: certificates are issued and revoked where the CA key is kept" in err
    status, _, err = run_keys(capsys, trusted, "revoke", "carol")
    assert status == 2 and "no identity 'carol'" in err and err.count("\n") == 1


# -- the Pi's store ------------------------------------------------------------------------------------
def test_export_gives_the_pi_what_it_runs_with_and_no_private_key_of_anyone_else(trusted, tmp_path, capsys):
    pi = KeyStore(tmp_path / "pi", "elettra")
    status, out, err = run_keys(capsys, trusted, "export", *PI, "-o", str(pi.dir))
    assert status == 0, err
    clients_alone = ["alice", "bob", "ntrip", "observer", "pilot", "sim"]
    assert sorted(p.name for p in pi.dir.iterdir()) == sorted(
        ["ca.pem", "crl.pem", *(f"{n}.pem" for n in PI + clients_alone), *(f"{n}.key" for n in PI)])
    assert "alice, bob, ntrip, observer, pilot, sim by certificate alone" in out
    assert pi.crl.read_bytes() == trusted.crl.read_bytes()
    for name in PI:
        assert pi.identity(name).name == name
    conf = load_zenoh_config(mode="router", listen=["tls/127.0.0.1:7447"])
    admitted = {i.name: (i.role, i.common_name) for i in secure_router(conf, pi)}   # no ca.key there
    assert admitted["alice"] == ("pilot", trusted.identity("alice").common_name)
    assert admitted["bob"] == ("observer", trusted.identity("bob").common_name)


def test_exporting_again_carries_revocations_and_drops_what_is_no_longer_vouched_for(trusted, tmp_path):
    pi = KeyStore(tmp_path / "pi", "elettra")
    trusted.export(PI, pi)
    trusted.revoke("bob")
    trusted.issue("pilot", "alice", force=True)
    with pytest.raises(SecurityError, match=r"router\.key: exists; not replaced \(--force replaces it\)"):
        trusted.export(PI, pi)
    trusted.export(PI, pi, force=True)
    assert not (pi.dir / "bob.pem").exists()
    assert pi.certificate(pi.dir / "alice.pem").common_name == trusted.identity("alice").common_name
    assert [r.name for r in pi.revocations()] == ["bob", "alice"]          # named from revoked/
    assert sorted(p.stem for p in pi.dir.glob("*.key")) == sorted(PI)      # never ca.key, no person's


def test_export_refuses_another_cars_store(trusted, tmp_path):
    other = KeyStore(tmp_path / "other", "elettra")
    other.init()
    with pytest.raises(SecurityError, match=r"ca\.pem: another CA is there"):
        trusted.export(["estimator"], other)
    assert (other.dir / "ca.key").exists()
