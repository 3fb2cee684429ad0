"""On a secured car a device may ask whether its own liveliness token is taken (so a second
gnss0 is refused at start, common/service.py), and only its own (common/access.py)."""
from __future__ import annotations

import pytest
import zenoh
from vienatest import PYTHON, wait_until

from viena.common.config import load_zenoh_config
from viena.common.secure import secure_client

pytestmark = pytest.mark.slow  # a TLS router and processes

CAR = "viena/elettra"


def session(store, name: str, port: int):
    conf = load_zenoh_config(mode="client", connect=[f"tls/localhost:{port}"])
    secure_client(conf, store, name)
    return zenoh.open(conf)


def alive(s, key: str) -> list[str]:
    return [str(r.ok.key_expr) for r in s.liveliness().get(key, timeout=2.0) if r.ok is not None]


def test_a_device_sees_its_own_token_taken_and_no_other(store, tls_router):
    with session(store, "gnss0", tls_router) as holder, session(store, "gnss0", tls_router) as second, \
            session(store, "gnss1", tls_router) as other:
        token = holder.liveliness().declare_token(f"{CAR}/alive/gnss/gnss0")
        try:
            # the token reaches the router in its own time (a busy machine can take a while)
            assert wait_until(lambda: alive(second, f"{CAR}/alive/gnss/gnss0") == [f"{CAR}/alive/gnss/gnss0"], 20)
            assert alive(other, f"{CAR}/alive/gnss/gnss0") == []            # not its key
            assert alive(other, f"{CAR}/alive/gnss/gnss1") == []            # free
        finally:
            token.undeclare()


def test_a_second_gnss0_on_the_secured_car_is_refused(store, tls_router, procs):
    endpoint = f"tls/localhost:{tls_router}"
    with session(store, "gnss0", tls_router) as holder:
        token = holder.liveliness().declare_token(f"{CAR}/alive/gnss/gnss0")
        try:
            proc = procs.start(PYTHON, "-m", "viena.services.gnss.service", "--connect", endpoint,
                               "--keys", str(store.dir), "--port", "socket://127.0.0.1:9")
            assert proc.wait(timeout=30) == 2
            err = proc.stderr.read().strip().splitlines()
            assert len(err) == 1 and "gnss0 already runs on car elettra" in err[0], err
        finally:
            token.undeclare()
