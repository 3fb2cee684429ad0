"""A program `viena up` starts finds its identity's files and does not check them again
while `viena up`'s check holds: the check loads cryptography, some 10 MB of every process
on the Pi (`viena bench pi`). A revocation, a new export or an expiry since makes the
program check afresh; a tool a person starts always checks."""
from __future__ import annotations

import subprocess
import sys
import time

import pytest
import zenoh

from viena.common.keystore import KeyStore, SecurityError
from viena.common.secure import IDENTITIES_CHECKED, checked_identities, secure_client, still_checked
from viena.compose import profile_file
from viena.profile_security import secure_environment

PRESENT = """
import sys, zenoh
from viena.common.keystore import KeyStore
from viena.common.secure import secure_client
conf = zenoh.Config()
secure_client(conf, KeyStore(sys.argv[1], "elettra"), "gnss0", checked=sys.argv[2] or None)
print(conf.get_json("transport/link/tls/connect_certificate"), "cryptography" in sys.modules)
"""


@pytest.fixture
def store(tmp_path):
    store = KeyStore(tmp_path / "keys", "elettra")
    store.init()
    return store


def checked_by_viena_up(store, profile: str = "pi") -> str:
    env = {"VIENA_SETTINGS": str(profile_file(profile).with_suffix(".toml")), "VIENA_RTK": "false",
           "VIENA_RECORD": "true", "VIENA_LINK": "tls"}
    return secure_environment(profile_file(profile), env, True, False, str(store.dir))[IDENTITIES_CHECKED]


def present(store, checked: str) -> list[str]:
    return subprocess.run([sys.executable, "-c", PRESENT, str(store.dir), checked], capture_output=True, text=True,
                          timeout=60, check=True).stdout.split()


def test_an_identity_viena_up_checked_is_presented_without_loading_cryptography(store):
    checked = checked_by_viena_up(store)
    assert present(store, checked) == [f'"{store.dir / "gnss0.pem"}"', "False"]
    assert present(store, "") == [f'"{store.dir / "gnss0.pem"}"', "True"]      # a person's tool checks


def test_a_revocation_after_viena_up_is_checked_when_the_program_starts_again(store):
    checked = checked_by_viena_up(store)
    assert still_checked(store, "gnss0", checked)
    kept = {p.name: p.read_bytes() for p in (store.dir / "gnss0.pem", store.dir / "gnss0.key")}
    time.sleep(0.01)                                         # ctime resolution: the revocation comes later
    store.revoke("gnss0")                                    # a new revocation list, copied onto the Pi ...
    for name, data in kept.items():                          # ... where the old certificate stayed
        (store.dir / name).write_bytes(data)
    assert not still_checked(store, "gnss0", checked) and not still_checked(store, "gnss1", checked)
    with pytest.raises(SecurityError, match="revoked"):
        secure_client(zenoh.Config(), store, "gnss0", checked=checked)


def test_a_new_export_copied_over_the_store_is_checked_again(store):
    checked = checked_by_viena_up(store)
    time.sleep(0.01)
    key = store.dir / "gnss1.key"
    key.write_bytes(key.read_bytes())                        # what rsync does to a changed file
    assert not still_checked(store, "gnss1", checked) and still_checked(store, "gnss0", checked)


def test_a_check_holds_only_until_the_first_certificate_it_checked_expires(store):
    now = time.time()
    assert still_checked(store, "gnss0", checked_identities(["gnss0"], [now + 3600], now))
    assert not still_checked(store, "gnss0", checked_identities(["gnss0"], [now + 3600, now - 1], now))
    assert not still_checked(store, "gnss0", "1") and not still_checked(store, "gnss0", None)


def test_only_the_identities_viena_up_checked_skip_the_check(store):
    checked = checked_by_viena_up(store, "sim")
    assert "autopilot" in checked.split(":")[2].split(",")        # what the pilot program presents
    assert still_checked(store, "autopilot", checked) and not still_checked(store, "alice", checked)
    now = time.time()
    assert not still_checked(store, "gnss1", checked_identities(["gnss0"], [now + 3600], now))


def test_a_store_without_a_revocation_list_still_skips_it_and_a_new_file_in_it_does_not(store):
    store.crl.unlink()                                       # a store from before revocation lists
    checked = checked_by_viena_up(store)
    assert still_checked(store, "gnss0", checked)
    time.sleep(0.01)
    (store.dir / "gnss0.pem").rename(store.dir / "gnss0.old")   # replaced by another file ...
    (store.dir / "gnss0.old").rename(store.dir / "gnss0.pem")   # ... of the same name: the directory says so
    assert not still_checked(store, "gnss0", checked)


def test_a_checked_identity_whose_key_is_gone_is_refused_in_one_line(store):
    checked = checked_by_viena_up(store)
    (store.dir / "gnss1.key").unlink()
    with pytest.raises(SecurityError, match="gnss1"):
        secure_client(zenoh.Config(), store, "gnss1", checked=checked)


def test_a_store_made_before_the_black_box_starts_the_car_without_it_and_nothing_else_is_let_off(store, capsys):
    from viena.compose import _secure_environment
    from viena.profile_security import SecurityRefusal

    env = {"VIENA_SETTINGS": str(profile_file("pi").with_suffix(".toml")), "VIENA_RTK": "false",
           "VIENA_RECORD": "true", "VIENA_LINK": "tls"}
    for suffix in (".pem", ".key"):
        (store.dir / f"recorder{suffix}").unlink()
    out = _secure_environment(profile_file("pi"), env, True, False, str(store.dir), False)
    assert env["VIENA_RECORD"] == "false" and "recorder" not in out[IDENTITIES_CHECKED].split(":")[2].split(",")
    assert "no `recorder` identity" in capsys.readouterr().err
    env["VIENA_RECORD"] = "true"
    (store.dir / "gnss0.key").unlink()                       # a second one missing: refused, as before
    with pytest.raises(SecurityRefusal) as refused:
        _secure_environment(profile_file("pi"), env, True, False, str(store.dir), False)
    assert set(refused.value.failed) == {"recorder", "gnss0"}


PILOT = """
import sys
from viena.common.service import build_parser
from viena.services.pilot.service import PilotService
args = build_parser(PilotService).parse_args(["--connect", "tls/127.0.0.1:7447", "--keys", sys.argv[1]])
conf = PilotService(args).zenoh_config
print(conf.get_json("transport/link/tls/connect_certificate"), "cryptography" in sys.modules)
"""


def test_the_pilot_program_presents_autopilot_only_and_checked_loads_no_cryptography(store):
    """It once built its session as `pilot` (a person's identity) before `autopilot`: checked
    afresh, with cryptography, and refused on a car whose store has no `pilot`."""
    checked = checked_by_viena_up(store, "sim")                # a profile with the pilot in it
    run = subprocess.run([sys.executable, "-c", PILOT, str(store.dir)], capture_output=True, text=True, timeout=60,
                         env={**__import__("os").environ, IDENTITIES_CHECKED: checked})
    assert run.stdout.split() == [f'"{store.dir / "autopilot.pem"}"', "False"], run.stderr
