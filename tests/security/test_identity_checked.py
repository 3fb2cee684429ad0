"""A program `viena up` starts finds its identity's files and does not check them again:
`viena up` checked every program's identity just before, and the check loads cryptography,
some 10 MB of every process on the Pi (`viena bench pi`). A tool a person starts checks."""
from __future__ import annotations

import subprocess
import sys

import pytest

from viena.common.keystore import KeyStore, SecurityError
from viena.common.secure import IDENTITIES_CHECKED, secure_client
from viena.compose import profile_file
from viena.profile_security import secure_environment

PRESENT = """
import sys, zenoh
from viena.common.keystore import KeyStore
from viena.common.secure import secure_client
conf = zenoh.Config()
secure_client(conf, KeyStore(sys.argv[1], "elettra"), "gnss0", checked=sys.argv[2] == "1")
print(conf.get_json("transport/link/tls/connect_certificate"), "cryptography" in sys.modules)
"""


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    store = KeyStore(tmp_path_factory.mktemp("keys"), "elettra")
    store.init()
    return store


@pytest.mark.parametrize("checked", [True, False])
def test_a_checked_identity_is_presented_without_loading_cryptography(store, checked):
    out = subprocess.run([sys.executable, "-c", PRESENT, str(store.dir), "1" if checked else "0"],
                         capture_output=True, text=True, timeout=60, check=True).stdout.split()
    assert out == [f'"{store.dir / "gnss0.pem"}"', "False" if checked else "True"]


def test_a_checked_identity_whose_key_is_gone_is_still_refused_in_one_line(store, tmp_path):
    (store.dir / "gnss1.key").rename(tmp_path / "gnss1.key")
    try:
        with pytest.raises(SecurityError, match="no gnss1.key in"):
            secure_client(__import__("zenoh").Config(), store, "gnss1", checked=True)
    finally:
        (tmp_path / "gnss1.key").rename(store.dir / "gnss1.key")


def test_viena_up_tells_its_programs_it_checked_their_identities(store, monkeypatch):
    env = {"VIENA_SETTINGS": str(profile_file("pi").with_suffix(".toml")), "VIENA_RTK": "false",
           "VIENA_RECORD": "true", "VIENA_LINK": "tls"}
    assert secure_environment(profile_file("pi"), env, True, False, str(store.dir))[IDENTITIES_CHECKED] == "1"
    assert IDENTITIES_CHECKED not in secure_environment(profile_file("pi"), env, False, True, str(store.dir))
