"""The plan's security check: who can reach the mission from the network, and what they can do.

:func:`check_security` reads a validated :class:`~mission.core.plan_types.Plan` and returns one
:class:`SecurityFinding` per exposure, each one line, at one of three levels:

- ``refuse``: the plan is not flown (:class:`PlanSecurityError`, exit status 2 in every command
  that loads a plan): a zenoh endpoint another machine can reach, the operator commands enabled
  (``[control] remote``), and nothing proving who commands (TLS client certificates on every
  such endpoint, or ``[zenoh.access_control]``, whose commanders are certificate names or
  logins), unless the plan says ``[zenoh] allow_unauthenticated_network = true``; a vehicle link
  that is not loopback and not signed when ``[security] require_signing = true``;
- ``warn``: flown, but ``dry-run``, ``fly``, ``resume`` and ``watch`` say it on every start: the
  allowed open command channel, readings accepted from peers that prove no identity (they can
  steer the formation within the geofence), an unsigned vehicle link that is not loopback, a
  ``[forward]`` client that may command;
- ``info``: stated: telemetry forwarded off this machine, commands through a zenoh router, who
  may command.

"Reachable from the network" is :func:`wire.loopback.host_is_loopback`'s rule; the check takes
the rule as an argument (``is_loopback``) so that tests can declare a loopback address to be a
network one. The threat model behind each line is ``docs/security.md``.
"""
from __future__ import annotations

from dataclasses import dataclass

from mission.core.plan_sections import parse_forward_out
from mission.core.plan_types import Plan, PlanError
from mission.core.uri import parse_connection
from mission.core.zenoh_config import ZenohPlan
from wire.loopback import IsLoopback, host_is_loopback, zenoh_endpoint_is_loopback

__all__ = ["LEVELS", "SecurityFinding", "PlanSecurityError", "check_security", "refusals"]

#: the levels of a finding, most severe first
LEVELS = ("refuse", "warn", "info")
_TLS_PROTOCOLS = ("tls/", "quic/")
_FIX = "docs/security.md"


@dataclass(frozen=True)
class SecurityFinding:
    """One exposure of the plan.

    Attributes
    ----------
    level : str
        ``refuse``, ``warn`` or ``info`` (:data:`LEVELS`).
    key : str
        The dotted plan key it is about (``zenoh.listen``, ``vehicles[0].connection``, ...).
    text : str
        One line: what is exposed, what an attacker could do, how to close it.
    """

    level: str
    key: str
    text: str

    def line(self) -> str:
        """``"LEVEL  KEY: TEXT"``, as ``dry-run`` prints it."""
        return f"{self.level:<6} {self.key}: {self.text}"

    def to_json(self) -> dict:
        """``{"level", "key", "text"}`` (the mission log's plan record, the state publication)."""
        return {"level": self.level, "key": self.key, "text": self.text}


class PlanSecurityError(PlanError):
    """A plan the security check refuses; ``problems`` as :class:`PlanError`, one line each."""

    def __init__(self, findings: list[SecurityFinding], source: str | None = None):
        super().__init__([(f.key, f.text) for f in findings], source)
        where = f" ({source})" if source else ""
        ValueError.__init__(self, "\n".join(f"refused{where}: {f.key}: {f.text}" for f in findings))


def check_security(plan: Plan, *, is_loopback: IsLoopback = host_is_loopback) -> list[SecurityFinding]:
    """Every exposure of ``plan``, most severe first (see the module docstring).

    Parameters
    ----------
    plan : Plan
        A validated plan (``[forward] out`` with any ``--out`` already merged).
    is_loopback : callable
        ``host -> bool``: only this machine reaches it (default :func:`wire.loopback.host_is_loopback`).

    Returns
    -------
    list of SecurityFinding
        Sorted by level (``refuse``, ``warn``, ``info``); empty for a plan on loopback only.
    """
    findings = (_zenoh_findings(plan.zenoh, plan.fleet, plan.control.remote, is_loopback)
                + _vehicle_findings(plan, is_loopback) + _forward_findings(plan, is_loopback))
    return sorted(findings, key=lambda f: LEVELS.index(f.level))


def refusals(findings: list[SecurityFinding]) -> list[SecurityFinding]:
    """The findings at level ``refuse``."""
    return [f for f in findings if f.level == "refuse"]


def _zenoh_findings(z: ZenohPlan, fleet: str, remote: bool, is_loopback: IsLoopback) -> list[SecurityFinding]:
    """Network endpoints: who may command, who may put readings, what a router decides."""
    exposed = [("zenoh.listen", ep) for ep in z.listen if not zenoh_endpoint_is_loopback(ep, is_loopback)]
    exposed += [("zenoh.connect", ep) for ep in z.connect if not zenoh_endpoint_is_loopback(ep, is_loopback)]
    if not exposed:
        if z.allow_unauthenticated_network:
            return [SecurityFinding("info", "zenoh.allow_unauthenticated_network",
                                    "set, but every zenoh endpoint is loopback: nothing to allow")]
        return []
    # a peer proves who it is on an endpoint with TLS client certificates; the access control
    # (default deny) lets only named certificates or logins put readings, watch, command
    open_eps = [] if z.access_control is not None else [
        (k, ep) for k, ep in exposed if not (ep.startswith(_TLS_PROTOCOLS) and z.enable_mtls)]
    out = [_who_commands(z, open_eps, fleet)] if remote else []
    if open_eps:
        eps = ", ".join(ep for _, ep in open_eps)
        out.append(SecurityFinding(
            "warn", "zenoh.access_control",
            f"readings are accepted from unauthenticated peers on {eps}: anyone who reaches it can put "
            f"readings for any vehicle and so steer the formation anywhere within the geofence (the "
            f"coordinator rejects only inconsistent readings), and watch the mission; add TLS client "
            f"certificates or [zenoh.access_control] sensor_* ({_FIX})"))
    if z.mode == "client":
        routers = ", ".join(ep for k, ep in exposed if k == "zenoh.connect") or "a router"
        out.append(SecurityFinding(
            "info", "zenoh.mode", f"routed through {routers}: who reaches the coordinator is also the "
            f"router's own configuration (its TLS, logins and access control; the plan does not write it)"))
    return out


def _who_commands(z: ZenohPlan, open_eps: list, fleet: str) -> SecurityFinding:
    """The command channel's finding: refused / warned when open, else who may command."""
    if open_eps:
        key = open_eps[0][0]
        eps = ", ".join(ep for _, ep in open_eps)
        if z.allow_unauthenticated_network:
            return SecurityFinding(
                "warn", "zenoh.allow_unauthenticated_network",
                f"true: anyone who reaches {eps} can command the fleet (swarmseek ctl {fleet} "
                f"land|abort|rtl|pause) and watch it; no identity is checked")
        return SecurityFinding(
            "refuse", key,
            f"{eps} can be reached from the network and any peer there could command the fleet "
            f"(swarmseek ctl {fleet} land|abort|rtl|pause) without proving who it is: add TLS client "
            f"certificates ([zenoh.tls] enable_mtls, tls/ endpoints) or logins with [zenoh.access_control] "
            f"commander_usernames ({_FIX}), listen on 127.0.0.1, set [control] remote = false, or accept "
            f"it with [zenoh] allow_unauthenticated_network = true")
    acl = z.access_control
    if acl is None:
        return SecurityFinding("info", "zenoh.tls.enable_mtls",
                               "commands, readings and the state only from peers with a certificate signed "
                               "by root_ca_certificate (name commanders in [zenoh.access_control] to narrow)")
    names = list(acl.commander_cert_common_names) + list(acl.commander_usernames)
    who = f"only from {', '.join(names)}" if names else "from no zenoh peer (the terminal's keys only)"
    return SecurityFinding("info", "zenoh.access_control", f"commands over zenoh {who}")


def _vehicle_findings(plan: Plan, is_loopback: IsLoopback) -> list[SecurityFinding]:
    """A vehicle link another machine or a radio can reach, without MAVLink 2 signing."""
    signing = plan.security
    if signing is not None and "*" not in signing.allow_unsigned:
        return []
    unsigned = ("not signed" if signing is None
                else "signed in migration mode (allow_unsigned = [\"*\"] accepts every unsigned frame)")
    out = []
    for j, vehicle in enumerate(plan.vehicles):
        spec = parse_connection(vehicle.connection)
        if spec.kind == "serial":
            reach = "anyone in range of that radio (or on that cable)"
        elif is_loopback(spec.host or ""):
            continue
        else:
            reach = "anyone on that network"
        level = "refuse" if plan.require_signing else "warn"
        why = "; [security] require_signing = true" if plan.require_signing else ""
        out.append(SecurityFinding(
            level, f"vehicles[{j}].connection",
            f"vehicle {vehicle.id} ({vehicle.connection}) is not loopback and its MAVLink is {unsigned}: "
            f"{reach} can command it (arm, mode, setpoints, land) and forge its telemetry; give "
            f"[security] signing_key_file ({_FIX}){why}"))
    return out


def _forward_findings(plan: Plan, is_loopback: IsLoopback) -> list[SecurityFinding]:
    """``[forward] out`` / ``--out`` clients off this machine."""
    out = []
    for j, address in enumerate(plan.forward.out):
        host, _port = parse_forward_out(address)
        if is_loopback(host):
            continue
        if plan.forward.allow_commands:
            out.append(SecurityFinding(
                "warn", f"forward.out[{j}]",
                f"every vehicle's telemetry leaves this machine to {address}, and frames from it are relayed to "
                f"the vehicles ([forward] allow_commands = true): whoever sends from that address commands them"))
        else:
            out.append(SecurityFinding(
                "info", f"forward.out[{j}]",
                f"every vehicle's telemetry leaves this machine to {address} (read-only: its frames reach the "
                f"vehicles only with [forward] allow_commands = true)"))
    return out
