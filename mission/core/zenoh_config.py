"""zenoh session settings of the plan and their translation into a ``zenoh.Config``.

:class:`ZenohPlan` (mode, endpoints, TLS, authentication, access control) is what the plan's
``[zenoh]`` table becomes (validated by :mod:`mission.core.zenoh_security`);
:meth:`ZenohPlan.to_config` and :func:`apply_security` write zenoh 1.x configuration:

- ``transport/link/tls/*`` (certificate and key file paths, ``enable_mtls``);
- ``transport/auth/usrpwd`` (``user``, ``password`` read from a file, ``dictionary_file``);
- ``access_control`` (:func:`acl_config`): default deny; sensor readings accepted only from the
  listed subjects, the coordinator's state sent only to the listed monitors.

Its names are imported from here (not through :mod:`mission.core.zenoh_security`).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field

from wire.zenoh_secrets import read_password_file

__all__ = [
    "ZENOH_MODES",
    "ZenohAuthPlan",
    "ZenohAclPlan",
    "ZenohPlan",
    "acl_config",
    "apply_security",
]

ZENOH_MODES = ("peer", "client", "router")


@dataclass(frozen=True)
class ZenohAuthPlan:
    """User/password authentication (zenoh ``transport/auth/usrpwd``).

    Attributes
    ----------
    username : str or None
        This session's user name, sent when it opens a link (with the password read from
        ``password_file``).
    password_file : str or None
        File holding the password on its first line (not world-readable).
    dictionary_file : str or None
        ``user:password`` lines; the peers this session accepts (not world-readable).
    """

    username: str | None = None
    password_file: str | None = None
    dictionary_file: str | None = None


@dataclass(frozen=True)
class ZenohAclPlan:
    """The plan's access-control form (``[zenoh.access_control]``), already bound to a fleet.

    Attributes
    ----------
    sensor_key_expr : str
        ``swarmseek/<fleet>/vehicle/*/sensor``.
    state_key_expr : str
        ``swarmseek/<fleet>/mission/**``.
    sensor_cert_common_names, sensor_usernames : tuple of str
        Subjects allowed to put readings.
    monitor_cert_common_names, monitor_usernames : tuple of str
        Subjects allowed to subscribe to the coordinator's state.
    commander_cert_common_names, commander_usernames : tuple of str
        Subjects allowed to send operator commands (queries on ``control_key_expr``).
    control_key_expr : str
        ``swarmseek/<fleet>/mission/control``.
    """

    sensor_key_expr: str
    state_key_expr: str
    sensor_cert_common_names: tuple[str, ...] = ()
    sensor_usernames: tuple[str, ...] = ()
    monitor_cert_common_names: tuple[str, ...] = ()
    monitor_usernames: tuple[str, ...] = ()
    commander_cert_common_names: tuple[str, ...] = ()
    commander_usernames: tuple[str, ...] = ()
    control_key_expr: str = ""


def acl_config(acl: ZenohAclPlan) -> dict:
    """zenoh's ``access_control`` section for the plan's form (default permission: deny).

    Rules: sensors may ``put`` readings (ingress) and learn of the coordinator's subscriber
    (egress ``declare_subscriber``); monitors may subscribe to the state (ingress
    ``declare_subscriber``) and receive it (egress ``put``); commanders may query the control key
    (ingress ``query``), learn of its queryable (egress ``declare_queryable``) and get the answer
    (egress ``reply``). Everything else is denied.
    """
    rules, subjects, policies = [], [], []
    groups = (("sensor", acl.sensor_cert_common_names, acl.sensor_usernames,
               [("ingress", "put", acl.sensor_key_expr),
                ("egress", "declare_subscriber", acl.sensor_key_expr)]),
              ("monitor", acl.monitor_cert_common_names, acl.monitor_usernames,
               [("ingress", "declare_subscriber", acl.state_key_expr),
                ("egress", "put", acl.state_key_expr)]),
              ("commander", acl.commander_cert_common_names, acl.commander_usernames,
               [("ingress", "query", acl.control_key_expr),
                ("egress", "declare_queryable", acl.control_key_expr),
                ("egress", "reply", acl.control_key_expr)]))
    for name, cns, users, flows in groups:
        if not (cns or users):
            continue
        rule_ids = []
        for flow, message, key_expr in flows:
            rule_id = f"{name}-{flow}-{message}"
            rules.append({"id": rule_id, "permission": "allow", "flows": [flow],
                          "messages": [message], "key_exprs": [key_expr]})
            rule_ids.append(rule_id)
        for kind, names in (("cert_common_names", cns), ("usernames", users)):
            if names:
                subject_id = f"{name}-{kind}"
                subjects.append({"id": subject_id, kind: list(names)})
                policies.append({"id": f"{subject_id}-policy", "rules": rule_ids,
                                 "subjects": [subject_id]})
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}


def apply_security(conf, *, tls: dict | None = None, enable_mtls: bool = False,
                   auth: ZenohAuthPlan | None = None, acl: ZenohAclPlan | None = None) -> None:
    """Insert TLS, authentication and access control into a ``zenoh.Config`` (in place).

    Parameters
    ----------
    conf : zenoh.Config
        The session configuration.
    tls : dict, optional
        ``transport/link/tls`` file keys (see :data:`wire.zenoh_config.TLS_FILE_KEYS`) to paths.
    enable_mtls : bool
        Require and present client certificates.
    auth : ZenohAuthPlan, optional
        The password is read from its file now.
    acl : ZenohAclPlan, optional
        Access control (see :func:`acl_config`).

    Raises
    ------
    ZenohSecurityError
        The password file cannot be used.
    """
    for key, path in (tls or {}).items():
        conf.insert_json5(f"transport/link/tls/{key}", json.dumps(str(path)))
    if enable_mtls:
        conf.insert_json5("transport/link/tls/enable_mtls", "true")
    if auth is not None:
        usrpwd = {}
        if auth.username is not None and auth.password_file is not None:
            usrpwd["user"] = auth.username
            usrpwd["password"] = read_password_file(auth.password_file)
        if auth.dictionary_file is not None:
            usrpwd["dictionary_file"] = str(auth.dictionary_file)
        if usrpwd:
            conf.insert_json5("transport/auth/usrpwd", json.dumps(usrpwd))
    if acl is not None:
        conf.insert_json5("access_control", json.dumps(acl_config(acl)))


@dataclass(frozen=True)
class ZenohPlan:
    """zenoh session: mode, explicit endpoints, TLS, authentication, access control.

    Attributes
    ----------
    mode : str
        ``peer``, ``client`` or ``router``.
    listen, connect : tuple of str
        Endpoints (``tcp/HOST:PORT``, ``tls/HOST:PORT``).
    tls : dict
        ``transport/link/tls`` file keys to absolute paths.
    enable_mtls : bool
        Client certificates required and presented (mutual TLS).
    auth : mission.core.zenoh_security.ZenohAuthPlan or None
        User/password authentication.
    access_control : mission.core.zenoh_security.ZenohAclPlan or None
        Who may put readings and read the state (see ``docs/zenoh.md``).
    allow_unauthenticated_network : bool
        The operator's explicit consent to a network endpoint (not loopback) on which peers
        that prove no identity may command the mission: without it such a plan is refused
        (:mod:`mission.core.plan_security`, ``docs/security.md``); with it every start warns.
    """

    mode: str = "peer"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    tls: dict = field(default_factory=dict)
    enable_mtls: bool = False
    auth: ZenohAuthPlan | None = None
    access_control: ZenohAclPlan | None = None
    allow_unauthenticated_network: bool = False

    def __post_init__(self):
        # A plan read back from a mission log (``dataclasses.asdict``) holds plain dicts/lists.
        if isinstance(self.auth, dict):
            object.__setattr__(self, "auth", ZenohAuthPlan(**self.auth))
        if isinstance(self.access_control, dict):
            acl = {k: v if isinstance(v, str) else tuple(v) for k, v in self.access_control.items()}
            object.__setattr__(self, "access_control", ZenohAclPlan(**acl))

    def to_config(self):
        """A ``zenoh.Config``: explicit endpoints, multicast scouting off, security applied.

        Raises
        ------
        wire.zenoh_secrets.ZenohSecurityError
            The password file became unusable since the plan was loaded.
        """
        import zenoh

        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps(self.mode))
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        conf.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        apply_security(conf, tls=self.tls, enable_mtls=self.enable_mtls, auth=self.auth,
                       acl=self.access_control)
        return conf
