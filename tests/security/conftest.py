"""Fixtures of the security tests: a key store in a temporary directory (tests never use
real key material), and a TLS router that enforces it."""
from __future__ import annotations

import pytest
from vienatest import free_port, wait_for_port

from viena.common.keystore import KeyStore


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> KeyStore:
    """The car's CA, router and standard identities, made by `viena keys init`."""
    from viena.keys_cli import main

    directory = tmp_path_factory.mktemp("keys") / "elettra"
    assert main(["--keys", str(directory), "init"]) == 0
    return KeyStore(directory, "elettra")


@pytest.fixture
def tls_router(procs, store):
    """A `viena router` listening on TLS with the store's access control; its port."""
    port = free_port()
    procs.python("-m", "viena.router", "--listen", f"tls/127.0.0.1:{port}", "--keys", str(store.dir),
                 "--log-level", "WARNING")
    wait_for_port(port)
    return port
