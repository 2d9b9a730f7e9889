"""zenoh transport security from the plan: TLS, user/password authentication, access control.

The plan's ``[zenoh.tls]``, ``[zenoh.auth]`` and ``[zenoh.access_control]`` tables (see
``docs/zenoh.md``) are validated here (every problem reported with its dotted key, through the
plan's :class:`~mission.core.plan_checks.Checker`) and turned into zenoh 1.x configuration:

- ``transport/link/tls/*`` (certificate and key file paths, ``enable_mtls``);
- ``transport/auth/usrpwd`` (``user``, ``password`` read from a file, ``dictionary_file``);
- ``access_control``: default deny; sensor readings (``put`` on
  ``swarmseek/<fleet>/vehicle/*/sensor``) accepted only from subjects named by certificate common
  name or user name, and the coordinator's state (``swarmseek/<fleet>/mission/**``) sent only to
  the listed monitors.

Secrets never sit in the plan itself: the password is read from ``password_file``, which, like
the dictionary and the private keys, must not be world-readable.
"""
from __future__ import annotations

import json
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path

from mission.core.plan_checks import Checker, show_value

__all__ = [
    "ZENOH_MODES",
    "ZenohPlan",
    "parse_zenoh",
    "TLS_FILE_KEYS",
    "ZenohSecurityError",
    "ZenohAuthPlan",
    "ZenohAclPlan",
    "private_file_problem",
    "read_password_file",
    "acl_config",
    "apply_security",
    "parse_tls",
    "parse_auth",
    "parse_access_control",
]

ZENOH_MODES = ("peer", "client", "router")
TLS_FILE_KEYS = ("root_ca_certificate", "listen_certificate", "listen_private_key",
                 "connect_certificate", "connect_private_key")
_PRIVATE_TLS_KEYS = ("listen_private_key", "connect_private_key")
_NAME_CHARS_FORBIDDEN = ":\n\r"


class ZenohSecurityError(ValueError):
    """A secret file that cannot be used (missing, world-readable, malformed)."""


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
    """

    sensor_key_expr: str
    state_key_expr: str
    sensor_cert_common_names: tuple[str, ...] = ()
    sensor_usernames: tuple[str, ...] = ()
    monitor_cert_common_names: tuple[str, ...] = ()
    monitor_usernames: tuple[str, ...] = ()


def private_file_problem(path: str | Path) -> str | None:
    """Why ``path`` cannot hold a secret (missing, not a file, world-readable), or None."""
    p = Path(path)
    if not p.is_file():
        return f"file not found: {p}"
    if os.name == "posix" and p.stat().st_mode & stat.S_IROTH:
        return f"{p} is world-readable; run chmod 600 {p}"
    return None


def read_password_file(path: str | Path) -> str:
    """The password on the first line of ``path`` (trailing newline stripped).

    Raises
    ------
    ZenohSecurityError
        The file is missing, world-readable, not UTF-8 or its first line is empty.
    """
    why = private_file_problem(path)
    if why:
        raise ZenohSecurityError(why)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ZenohSecurityError(f"cannot read {path}: {exc}") from None
    lines = text.splitlines()
    if not lines or not lines[0]:
        raise ZenohSecurityError(f"{path}: the first line (the password) is empty")
    return lines[0]


def acl_config(acl: ZenohAclPlan) -> dict:
    """zenoh's ``access_control`` section for the plan's form (default permission: deny).

    Rules: sensors may ``put`` readings (ingress) and learn of the coordinator's subscriber
    (egress ``declare_subscriber``); monitors may subscribe to the state (ingress
    ``declare_subscriber``) and receive it (egress ``put``). Everything else is denied.
    """
    rules, subjects, policies = [], [], []
    groups = (("sensor", acl.sensor_cert_common_names, acl.sensor_usernames,
               [("ingress", "put", acl.sensor_key_expr),
                ("egress", "declare_subscriber", acl.sensor_key_expr)]),
              ("monitor", acl.monitor_cert_common_names, acl.monitor_usernames,
               [("ingress", "declare_subscriber", acl.state_key_expr),
                ("egress", "put", acl.state_key_expr)]))
    for name, cns, users, flows in groups:
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
        ``transport/link/tls`` file keys (see :data:`TLS_FILE_KEYS`) to paths.
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


def _resolve(value: str, base_dir: Path | None) -> Path:
    fp = Path(value)
    if not fp.is_absolute() and base_dir is not None:
        fp = base_dir / fp
    return fp


def parse_tls(c: Checker, t: dict, prefix: str, base_dir: Path | None,
              listen: tuple[str, ...], connect: tuple[str, ...]) -> tuple[dict, bool]:
    """Validate ``[zenoh.tls]``: returns ``(file key -> path, enable_mtls)``; problems go to ``c``."""
    c.unknown(t, TLS_FILE_KEYS + ("enable_mtls",), prefix)
    tls: dict[str, str] = {}
    for key in TLS_FILE_KEYS:
        if key not in t:
            continue
        v = c.string(t, key, prefix)
        if v is None:
            continue
        fp = _resolve(v, base_dir)
        why = private_file_problem(fp) if key in _PRIVATE_TLS_KEYS else (
            None if fp.is_file() else f"file not found: {fp}")
        if why:
            c.bad(f"{prefix}.{key}", why)
            continue
        tls[key] = str(fp)
    mtls = t.get("enable_mtls", False)
    if not isinstance(mtls, bool):
        c.bad(f"{prefix}.enable_mtls", f"must be true or false, got {show_value(mtls)}")
        mtls = False
    for side in ("listen", "connect"):
        pair = (f"{side}_certificate", f"{side}_private_key")
        if (pair[0] in t) != (pair[1] in t):
            missing = pair[1] if pair[0] in t else pair[0]
            present = pair[0] if missing == pair[1] else pair[1]
            if _reported(c, f"{prefix}.{present}"):
                continue
            c.bad(f"{prefix}.{missing}", f"required with {prefix}.{present}")
    if any(ep.startswith("tls/") for ep in listen):
        for key in ("listen_certificate", "listen_private_key"):
            if key not in t and not _reported(c, f"{prefix}.{key}"):
                c.bad(f"{prefix}.{key}", "required: a listen endpoint uses tls/")
    if any(ep.startswith("tls/") for ep in connect) and "root_ca_certificate" not in t:
        c.bad(f"{prefix}.root_ca_certificate", "required: a connect endpoint uses tls/")
    if mtls:
        if "root_ca_certificate" not in t:
            c.bad(f"{prefix}.root_ca_certificate", "required with enable_mtls = true")
        if not any(k in t for k in ("listen_certificate", "connect_certificate")):
            c.bad(f"{prefix}.enable_mtls", "needs a listen_certificate or connect_certificate "
                  "(with its private key)")
    return tls, mtls


def _reported(c: Checker, key: str) -> bool:
    return any(k == key for k, _ in c.problems)


def parse_auth(c: Checker, t: dict, prefix: str, base_dir: Path | None) -> ZenohAuthPlan | None:
    """Validate ``[zenoh.auth]`` (None when absent or invalid); problems go to ``c``."""
    if not t:
        return None
    c.unknown(t, ("username", "password_file", "dictionary_file"), prefix)
    if "password" in t:
        c.bad(f"{prefix}.password", "never put a password in the plan: use password_file")
    username = c.string(t, "username", prefix)
    if username is not None and any(ch in username for ch in _NAME_CHARS_FORBIDDEN):
        c.bad(f"{prefix}.username", f"must not contain ':' or line breaks, got {username!r}")
        username = None
    if ("username" in t) != ("password_file" in t):
        missing = "password_file" if "username" in t else "username"
        c.bad(f"{prefix}.{missing}", "username and password_file go together")
    files: dict[str, str | None] = {}
    for key in ("password_file", "dictionary_file"):
        files[key] = None
        v = c.string(t, key, prefix)
        if v is None:
            continue
        fp = _resolve(v, base_dir)
        try:
            if key == "password_file":
                read_password_file(fp)
            else:
                _check_dictionary(fp)
        except ZenohSecurityError as exc:
            c.bad(f"{prefix}.{key}", str(exc))
            continue
        files[key] = str(fp)
    if not any(k in t for k in ("username", "password_file", "dictionary_file")):
        c.bad(prefix, "give username + password_file, dictionary_file, or both")
    if username is None and files["dictionary_file"] is None:
        return None
    if username is not None and files["password_file"] is None:
        return None
    return ZenohAuthPlan(username=username, password_file=files["password_file"],
                         dictionary_file=files["dictionary_file"])


def _check_dictionary(path: Path) -> None:
    why = private_file_problem(path)
    if why:
        raise ZenohSecurityError(why)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ZenohSecurityError(f"cannot read {path}: {exc}") from None
    entries = [ln for ln in lines if ln.strip()]
    if not entries:
        raise ZenohSecurityError(f"{path}: no user:password line")
    for i, line in enumerate(lines, 1):
        if line.strip() and (":" not in line or not line.split(":", 1)[0] or not line.split(":", 1)[1]):
            raise ZenohSecurityError(f"{path} line {i}: expected user:password")


def parse_access_control(c: Checker, t: dict, prefix: str, fleet: str | None, *,
                         enable_mtls: bool, auth: ZenohAuthPlan | None,
                         listen: tuple[str, ...] = ()) -> ZenohAclPlan | None:
    """Validate ``[zenoh.access_control]`` (None when absent or invalid); problems go to ``c``."""
    if not t:
        return None
    keys = ("sensor_cert_common_names", "sensor_usernames", "monitor_cert_common_names",
            "monitor_usernames")
    c.unknown(t, ("default",) + keys, prefix)
    default = t.get("default", "deny")
    if default != "deny":
        c.bad(f"{prefix}.default", f"only \"deny\" is supported (an allow default could not keep "
              f"other peers from putting readings), got {show_value(default)}")
    names = {k: c.strings(t, k, prefix) for k in keys}
    if not names["sensor_cert_common_names"] and not names["sensor_usernames"]:
        c.bad(prefix, "give sensor_cert_common_names or sensor_usernames (else no reading is accepted)")
    for k in ("sensor_cert_common_names", "monitor_cert_common_names"):
        if names[k] and not enable_mtls:
            c.bad(f"{prefix}.{k}", "certificate names need [zenoh.tls] enable_mtls = true")
    for k in ("sensor_usernames", "monitor_usernames"):
        if names[k] and (auth is None or auth.dictionary_file is None):
            c.bad(f"{prefix}.{k}", "user names need [zenoh.auth] dictionary_file (to authenticate them)")
        elif names[k] and not listen:
            c.bad(f"{prefix}.{k}", "user names identify only peers that connect to this session: "
                  "give [zenoh] listen endpoints (or use certificate names)")
    if fleet is None:
        return None
    return ZenohAclPlan(sensor_key_expr=f"swarmseek/{fleet}/vehicle/*/sensor",
                        state_key_expr=f"swarmseek/{fleet}/mission/**", **names)


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
    """

    mode: str = "peer"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    tls: dict = field(default_factory=dict)
    enable_mtls: bool = False
    auth: ZenohAuthPlan | None = None
    access_control: ZenohAclPlan | None = None

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
        mission.core.zenoh_security.ZenohSecurityError
            The password file became unusable since the plan was loaded.
        """
        import json

        import zenoh

        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps(self.mode))
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        conf.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        apply_security(conf, tls=self.tls, enable_mtls=self.enable_mtls, auth=self.auth,
                       acl=self.access_control)
        return conf


def parse_zenoh(c: Checker, doc: dict, base_dir: Path | None) -> ZenohPlan:
    """Validate the plan's ``[zenoh]`` table; problems go to ``c`` with their dotted keys."""
    t = c.table(doc, "zenoh")
    p = "zenoh"
    c.unknown(t, ("mode", "listen", "connect", "tls", "auth", "access_control"), p)
    mode = c.string(t, "mode", p, "peer", choices=ZENOH_MODES)
    listen = c.strings(t, "listen", p)
    connect = c.strings(t, "connect", p)
    if "listen" in t or "connect" in t:
        if not listen and not connect:
            c.bad(p, "give at least one listen or connect endpoint (multicast scouting is off)")
    for j, ep in enumerate(listen + connect):
        if "/" not in ep:
            c.bad(f"{p}.{'listen' if j < len(listen) else 'connect'}",
                  f"endpoint {ep!r} must look like tcp/HOST:PORT or tls/HOST:PORT")
    tls, mtls = parse_tls(c, c.table(t, "tls", p), f"{p}.tls", base_dir, listen, connect)
    auth = parse_auth(c, c.table(t, "auth", p), f"{p}.auth", base_dir)
    fleet = doc.get("fleet") if isinstance(doc.get("fleet"), str) else None
    acl = parse_access_control(c, c.table(t, "access_control", p), f"{p}.access_control", fleet,
                               enable_mtls=mtls, auth=auth, listen=listen)
    return ZenohPlan(mode=mode or "peer", listen=listen, connect=connect, tls=tls,
                     enable_mtls=mtls, auth=auth, access_control=acl)
