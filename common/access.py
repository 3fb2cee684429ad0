"""Who may do what on a secured car: the roles, and zenoh access control built from them.

The router enforces these rules (zenoh `access_control`, default deny) on every client by
the certificate it presented (common/keystore.py). zenoh matches a client only by its
certificate's common name, so each identity's subject is the exact common name of its one
current certificate (NAME.TAG, unique to that certificate) and its rules are those of the
role that certificate carries: any other certificate of the name matches nothing and is
denied everything. Keys are relative to `viena/<car>/`; `{name}` is the identity's name (the
part of the common name before the dot), which for a device is its unit (gnss0, razor0).

What each word means to the router, for the client holding the role:

- publish K      it may put on K (ingress put)
- subscribe K    it may subscribe to K and receive what is put there (egress put)
- serve K        it may answer queries on K (declare a queryable, receive queries, reply)
- command K      it may query K and receive the replies
- receive K      it may subscribe to puts on K (a service taking commands as puts)
- token K        it may hold a liveliness token on K, and ask whether K is taken already
                 (a process refuses to start as a second gnss0: common/service.py)

Replies travel on the query's key expression, so a role that asks `steering/arm` needs
the replies on `steering/arm`; a wildcard query (`viena/**`) matches no narrower rule
and is refused, which keeps a discovery query from ever reaching a command. Every role
may see which keys exist (declarations and liveliness tokens flow to everyone), so
monitors can discover services.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from viena.common.keys import Keys
from viena.common.samples import topics as T

#: keys are the table's (common/samples/topics.py); `{name}` stands for the identity's name
STEERING_COMMANDS = tuple(t.key() for t in T.STEERING_COMMANDS)
STEERING_INPUTS = (T.STEERING_SETPOINT.key(), T.STEERING_ESTOP.key())
ESTOP = T.STEERING_ESTOP.key()
PILOT_COMMANDS = (T.PILOT_ROUTE.key(), T.PILOT_CMD.key())
ALIVE_ALL = T.ALIVE.key(service="**", unit=None)


def _below(*chunks: str) -> str:
    """Every key under a service's (or a unit's) own chunks: its samples and its health."""
    return "/".join([*chunks, "**"])


def _own(service: str) -> tuple[str, ...]:
    """What every process without units publishes about itself: its health and its info."""
    return (T.HEALTH.key(service=service, unit=None), T.INFO.key(service=service, unit=None))


def _token(service: str, unit: str | None = None) -> tuple[str, ...]:
    return (T.ALIVE.key(service=service, unit=unit),)


@dataclass(frozen=True)
class Role:
    summary: str
    publish: tuple[str, ...] = ()
    subscribe: tuple[str, ...] = ()
    serve: tuple[str, ...] = ()
    command: tuple[str, ...] = ()
    receive: tuple[str, ...] = ()
    token: tuple[str, ...] = ()
    liveliness: bool = False          # may watch and query liveliness tokens (discovery)


def _device(kind: str, summary: str = "publishes on its own keys only", subscribe: tuple[str, ...] = ()) -> Role:
    return Role(f"the {kind} service of one unit: {summary}", publish=(_below(kind, "{name}"),),
                subscribe=subscribe, token=_token(kind, "{name}"))


ROLES: dict[str, Role] = {
    "gnss": _device("gnss", "publishes on its own keys only; reads the corrections for its receiver",
                    subscribe=(T.GNSS_CORRECTIONS.key(),)),
    "imu": _device("imu"),
    "ntrip": Role("viena-ntrip: the corrections from an NTRIP caster; reads the fixes for the GGA a "
                  "caster may ask for",
                  publish=(T.GNSS_CORRECTIONS.key(), _below("ntrip")), subscribe=(T.GNSS_FIX.key(),),
                  token=_token("ntrip")),
    "steering": Role("the steering service: its state and health; answers the steering commands; reads "
                     "the car's speed from the estimator and the receivers",
                     publish=(T.STEERING_STATE.key(), *_own("steering")),
                     serve=STEERING_COMMANDS, subscribe=(T.ESTIMATOR_STATE.key(), T.GNSS_FIX.key()),
                     receive=STEERING_INPUTS, token=_token("steering")),
    "estimator": Role("the estimator: reads the devices, publishes the car's state",
                      publish=(_below("estimator"),),
                      subscribe=(T.GNSS_FIX.key(), T.IMU_SAMPLE.key()),
                      token=_token("estimator")),
    "sim": Role("the simulated car: publishes its ground truth; its simulated person reads the "
                "steering's state (to sweep the wheel when asked)",
                publish=(_below("sim"),), subscribe=(T.STEERING_STATE.key(),), token=_token("sim")),
    "autopilot": Role("viena-pilot: follows a route, steering with its own lease",
                      publish=(T.PILOT_STATE.key(), T.PILOT_PATH.key(), *_own("pilot"),
                               *STEERING_INPUTS),
                      subscribe=(T.ESTIMATOR_STATE.key(), T.STEERING_STATE.key(), ESTOP),
                      serve=PILOT_COMMANDS, receive=PILOT_COMMANDS,
                      command=(T.STEERING_ARM.key(), *STEERING_INPUTS), token=_token("pilot")),
    "pilot": Role("a person or program allowed to drive: arms, steers, calibrates, stops; sends "
                  "the autopilot its route and start/stop",
                  subscribe=("**",), command=(*STEERING_COMMANDS, *PILOT_COMMANDS),
                  publish=(*STEERING_INPUTS, *PILOT_COMMANDS),
                  token=_token("pilot", "{name}"), liveliness=True),
    "recorder": Role("the black box: reads every key, publishes its own health and info",
                     subscribe=("**",), publish=_own("recorder"),
                     token=_token("recorder")),
    "observer": Role("anyone else on the car: watches everything and may stop the car",
                     subscribe=("**",), publish=(ESTOP,), liveliness=True),
}


@dataclass
class _Policy:
    """Rules and subjects of one zenoh access_control block, built up identity by identity."""

    root: str
    rules: list[dict] = field(default_factory=list)
    subjects: list[dict] = field(default_factory=list)
    policies: list[dict] = field(default_factory=list)

    def allow(self, rule_ids: list[str], rule_id: str, messages: list[str], flow: str,
              keys: tuple[str, ...], name: str) -> None:
        if not keys:
            return
        self.rules.append({
            "id": rule_id, "permission": "allow", "flows": [flow], "messages": messages,
            "key_exprs": [f"{self.root}/{k.format(name=name)}" for k in keys]})
        rule_ids.append(rule_id)

    def add(self, name: str, role: Role, common_name: str) -> None:
        ids: list[str] = []
        r = f"{name}"
        self.allow(ids, f"{r}/publish", ["put", "delete"], "ingress", role.publish, name)
        self.allow(ids, f"{r}/subscribe", ["declare_subscriber"], "ingress", role.subscribe, name)
        self.allow(ids, f"{r}/subscribe-data", ["put", "delete"], "egress", role.subscribe, name)
        self.allow(ids, f"{r}/serve", ["declare_queryable", "reply"], "ingress", role.serve, name)
        self.allow(ids, f"{r}/serve-queries", ["query"], "egress", role.serve, name)
        self.allow(ids, f"{r}/command", ["query"], "ingress", role.command, name)
        self.allow(ids, f"{r}/command-replies", ["reply"], "egress", role.command, name)
        self.allow(ids, f"{r}/receive", ["declare_subscriber"], "ingress", role.receive, name)
        self.allow(ids, f"{r}/receive-data", ["put"], "egress", role.receive, name)
        self.allow(ids, f"{r}/token", ["liveliness_token"], "ingress", role.token, name)
        self.allow(ids, f"{r}/token-query", ["liveliness_query"], "ingress", role.token, name)
        self.allow(ids, f"{r}/token-replies", ["reply"], "egress", role.token, name)
        if role.liveliness:
            self.allow(ids, f"{r}/liveliness", ["declare_liveliness_subscriber", "liveliness_query"],
                       "ingress", (ALIVE_ALL,), name)
            self.allow(ids, f"{r}/liveliness-replies", ["reply"], "egress", (ALIVE_ALL,), name)
        ids.append("discovery")
        self.subjects.append({"id": name, "cert_common_names": [common_name]})
        self.policies.append({"id": name, "rules": ids, "subjects": [name]})


def access_control(car: str, identities: list[tuple[str, str, str]]) -> dict:
    """zenoh's `access_control` block for one car: default deny, then each (name, role,
    common name) allowed what its role says, to the certificate with that common name only.
    Unknown roles are skipped (they get nothing)."""
    policy = _Policy(Keys(car).prefix)
    policy.rules.append({
        "id": "discovery", "permission": "allow", "flows": ["egress"],
        "messages": ["declare_subscriber", "declare_queryable", "liveliness_token"],
        "key_exprs": [Keys(car).all]})
    for name, role, common_name in identities:
        if role in ROLES:
            policy.add(name, ROLES[role], common_name)
    return {"enabled": True, "default_permission": "deny", "rules": policy.rules,
            "subjects": policy.subjects, "policies": policy.policies}


def describe(role: str) -> str:
    """One line per permission, for `viena keys roles` and the README's table."""
    r = ROLES[role]
    parts = [f"{verb} {', '.join(keys)}" for verb, keys in (
        ("publish", r.publish), ("subscribe", r.subscribe), ("serve", r.serve),
        ("command", r.command), ("receive puts on", r.receive), ("token", r.token)) if keys]
    return "; ".join(parts)
