"""The bridge offers the e-stop only where its identity's role may put it (common/access.py)."""
from __future__ import annotations

import pytest

from viena.foxglove import build_parser, estop_allowed
from viena.tool import Connection


@pytest.fixture(scope="module")
def keys(tmp_path_factory):
    from viena.keys_cli import main

    directory = tmp_path_factory.mktemp("keys") / "elettra"
    assert main(["--keys", str(directory), "init"]) == 0
    return directory


def allowed(*argv: str) -> bool:
    args = build_parser().parse_args(list(argv))
    may, why = estop_allowed(args, Connection(args))
    assert "role" in why or "open link" in why or why == "--no-estop", why     # decided, not failed
    return may


@pytest.mark.parametrize("identity, expected", [("observer", True), ("pilot", True), ("estimator", False),
                                                ("gnss0", False), ("sim", False)])
def test_on_a_secured_car_only_roles_that_may_stop_get_the_estop(keys, identity, expected):
    assert allowed("--connect", "tls/127.0.0.1:7447", "--keys", str(keys), "--identity", identity) is expected


def test_on_an_open_link_anyone_may_and_no_estop_means_none(keys):
    assert allowed("--connect", "tcp/127.0.0.1:7447") is True
    assert allowed("--connect", "tcp/127.0.0.1:7447", "--no-estop") is False
    assert allowed("--connect", "tls/127.0.0.1:7447", "--keys", str(keys), "--no-estop") is False
