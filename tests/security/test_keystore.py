"""The key store: what `viena keys` writes, and every way a key can be unusable, each
refused with one line naming the file and the fix."""
from __future__ import annotations

import datetime as dt
import shutil
import stat

import pytest

from viena.common.keystore import STANDARD_IDENTITIES, KeyStore, SecurityError
from viena.keys_cli import main as keys


def run_keys(capsys, directory, *args) -> tuple[int, str, str]:
    status = keys(["--keys", str(directory), *args])
    out, err = capsys.readouterr()
    return status, out, err


@pytest.fixture
def fresh(tmp_path) -> KeyStore:
    store = KeyStore(tmp_path / "elettra", "elettra")
    store.init(["192.168.4.1", "viena-pi"])
    return store


def test_init_writes_private_keys_0600_in_a_private_directory(fresh):
    assert stat.S_IMODE(fresh.dir.stat().st_mode) == 0o700
    keys_written = sorted(p.stem for p in fresh.dir.glob("*.key"))
    assert keys_written == sorted(["ca", "router", *STANDARD_IDENTITIES])
    for path in fresh.dir.glob("*.key"):
        assert stat.S_IMODE(path.stat().st_mode) == 0o600, path
    for name in ["router", *STANDARD_IDENTITIES]:
        assert fresh.identity(name).name == name


def test_router_certificate_names_the_pi(fresh):
    from cryptography import x509

    cert = x509.load_pem_x509_certificate(fresh.router().cert.read_bytes())
    names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    dns = names.get_values_for_type(x509.DNSName)
    ips = [str(a) for a in names.get_values_for_type(x509.IPAddress)]
    assert {"localhost", "viena-pi"} <= set(dns)
    assert {"127.0.0.1", "192.168.4.1"} <= set(ips)


def test_identities_carry_their_role(fresh):
    roles = {i.name: i.role for i in fresh.identities()}
    assert roles["gnss0"] == "gnss" and roles["razor0"] == "imu" and roles["pilot"] == "pilot"
    assert roles["router"] == "router"


def test_nothing_is_overwritten_silently(fresh, capsys):
    before = (fresh.dir / "pilot.key").read_bytes()
    status, _, err = run_keys(capsys, fresh.dir, "issue", "pilot", "pilot")
    assert status == 2 and "exists; not replaced (--force replaces it and revokes the old certificate)" in err
    status, _, err = run_keys(capsys, fresh.dir, "init")
    assert status == 2 and "a CA already exists" in err
    assert (fresh.dir / "pilot.key").read_bytes() == before
    status, _, _ = run_keys(capsys, fresh.dir, "issue", "pilot", "pilot", "--force")
    assert status == 0 and (fresh.dir / "pilot.key").read_bytes() != before
    assert fresh.identity("pilot").role == "pilot"


def test_private_keys_are_never_printed(tmp_path, capsys):
    directory = tmp_path / "k"
    outputs = [run_keys(capsys, directory, "init", "--router-host", "10.0.0.1"),
               run_keys(capsys, directory, "issue", "pilot", "alice"),
               run_keys(capsys, directory, "list"),
               run_keys(capsys, directory, "zenoh-config", "alice", "--connect", "tls/localhost:7447")]
    assert [status for status, _, _ in outputs] == [0, 0, 0, 0]
    for _, out, err in outputs:
        assert "PRIVATE KEY" not in out + err
    listing = outputs[2][1]
    assert "alice" in listing and "pilot" in listing and "expires" in listing


def test_a_person_is_issued_and_listed(fresh, capsys):
    status, out, _ = run_keys(capsys, fresh.dir, "issue", "observer", "bob", "--days", "30")
    assert status == 0 and "issued 'bob' (observer)" in out
    status, out, _ = run_keys(capsys, fresh.dir, "list")
    line = next(row for row in out.splitlines() if row.startswith("bob"))
    assert "observer" in line and "expires in" in line       # within the 30-day warning


@pytest.mark.parametrize("role, name, why", [
    ("wizard", "bob", "unknown role 'wizard'"),
    ("pilot", "Bob", "cannot name an identity"),
    ("pilot", "router", "cannot name an identity"),
    ("pilot", "ca", "cannot name an identity"),
    ("pilot", "crl", "cannot name an identity"),
    ("pilot", "../x", "cannot name an identity"),
    ("pilot", "bob.1234", "cannot name an identity"),       # the dot separates the name from its tag
])
def test_bad_issue_requests_are_one_line(fresh, capsys, role, name, why):
    status, out, err = run_keys(capsys, fresh.dir, "issue", role, name)
    assert status == 2 and why in err and err.count("\n") == 1 and "Traceback" not in err


@pytest.mark.parametrize("days", ["0", "-1", "3651"])
def test_days_out_of_range_is_one_line(fresh, capsys, days):
    status, out, err = run_keys(capsys, fresh.dir, "issue", "observer", "bob", "--days", days)
    assert status == 2 and out == "" and "Traceback" not in err
    assert err == f"viena keys: --days {days}: a certificate lasts from 1 to 3650 days\n"
    assert not (fresh.dir / "bob.pem").exists() and not (fresh.dir / "bob.key").exists()


def test_days_at_its_bounds(fresh):
    assert fresh.issue("observer", "brief", days=1).not_after - dt.datetime.now(dt.UTC) < dt.timedelta(days=1)
    assert fresh.issue("observer", "long", days=3650).role == "observer"


def test_missing_store(tmp_path):
    with pytest.raises(SecurityError, match=r"no keys for car 'elettra' in .*viena keys init"):
        KeyStore(tmp_path / "none", "elettra").identity("pilot")


def test_unknown_identity_lists_what_exists(fresh):
    with pytest.raises(SecurityError, match=r"no identity 'carol' .*have: autopilot, estimator, gnss0.*viena keys issue ROLE carol"):
        fresh.identity("carol")


def test_missing_key_file(fresh):
    (fresh.dir / "pilot.key").unlink()
    with pytest.raises(SecurityError, match=r"pilot\.key: missing"):
        fresh.identity("pilot")             # a process presenting it needs its key ...
    assert "pilot" in [i.name for i in fresh.client_identities()]     # ... the router does not


def test_loose_key_permissions(fresh):
    (fresh.dir / "pilot.key").chmod(0o644)
    with pytest.raises(SecurityError, match=r"pilot\.key: readable by others \(mode 0644\): run `chmod 600 "):
        fresh.identity("pilot")


def test_expired_certificate(fresh):
    long_ago = dt.datetime.now(dt.UTC) - dt.timedelta(days=40)
    fresh.issue("pilot", "old", days=10, valid_from=long_ago)
    with pytest.raises(SecurityError, match=r"old\.pem: expired on .*viena keys issue pilot old --force"):
        fresh.identity("old")
    assert "old" not in [i.name for i in fresh.client_identities()]     # the router won't list it


def test_certificate_from_another_car(fresh, tmp_path):
    other = KeyStore(tmp_path / "other", "elettra")
    other.init()
    for suffix in (".pem", ".key"):
        shutil.copy(other.dir / f"pilot{suffix}", fresh.dir / f"stranger{suffix}")
    (fresh.dir / "stranger.key").chmod(0o600)
    with pytest.raises(SecurityError, match=r"stranger\.pem: certificate is for 'pilot'"):
        fresh.identity("stranger")
    shutil.copy(other.dir / "pilot.pem", fresh.dir / "pilot.pem")
    with pytest.raises(SecurityError, match=r"pilot\.pem: not signed by this car's CA"):
        fresh.identity("pilot")


def test_key_of_another_certificate(fresh):
    shutil.copy(fresh.dir / "observer.key", fresh.dir / "pilot.key")
    with pytest.raises(SecurityError, match=r"pilot\.key: this key does not belong to .*pilot\.pem"):
        fresh.identity("pilot")


def test_unknown_role_in_a_certificate(fresh, monkeypatch):
    import viena.common.keystore as keystore

    monkeypatch.setitem(keystore.ROLES, "wizard", keystore.ROLES["observer"])
    fresh.issue("wizard", "merlin")
    monkeypatch.delitem(keystore.ROLES, "wizard")
    with pytest.raises(SecurityError, match=r"merlin\.pem: unknown role 'wizard'"):
        fresh.identity("merlin")


def test_not_a_certificate(fresh):
    (fresh.dir / "pilot.pem").write_text("hello\n")
    with pytest.raises(SecurityError, match=r"pilot\.pem: not a PEM certificate"):
        fresh.identity("pilot")


def test_export_carries_identities_but_never_the_ca_key(fresh, tmp_path, capsys):
    target = tmp_path / "laptop"
    status, out, _ = run_keys(capsys, fresh.dir, "export", "estimator", "alice-less", "-o", str(target))
    assert status == 2 and not target.exists()                 # unknown name: nothing copied
    status, out, _ = run_keys(capsys, fresh.dir, "export", "estimator", "pilot", "-o", str(target))
    assert status == 0
    others = sorted(f"{name}.pem" for name in ["router", *STANDARD_IDENTITIES] if name not in ("estimator", "pilot"))
    others.remove("router.pem")                                # a server, not a client: not exported unasked
    assert sorted(p.name for p in target.iterdir()) == sorted(
        ["ca.pem", "crl.pem", "estimator.key", "estimator.pem", "pilot.key", "pilot.pem", *others])
    laptop = KeyStore(target, "elettra")
    assert laptop.identity("estimator").role == "estimator"
    assert stat.S_IMODE((target / "estimator.key").stat().st_mode) == 0o600
    status, _, err = run_keys(capsys, fresh.dir, "export", "pilot", "-o", str(target))
    assert status == 2 and "exists; not replaced" in err
