"""Preflight: what each vehicle does when the ground station dies, from its failsafe parameters.

The coordinator streams position setpoints; when it stops (crash, power, link), only the
autopilot's own failsafes decide what follows:

* ArduPilot: ``FS_GCS_ENABLE`` (0 disabled: the vehicle holds its last GUIDED target, i.e.
  hovers until the battery failsafe; 1 RTL; 2 RTL (continue in AUTO); 3 SmartRTL or RTL;
  4 SmartRTL or land; 5 land; 6 auto DO_LAND_START or RTL; 7 brake or land) after
  ``FS_GCS_TIMEOUT`` seconds without a ground-station heartbeat.
* PX4: offboard loss after ``COM_OF_LOSS_T`` s, action ``COM_OBL_RC_ACT`` (0 position, 1
  altitude, 2 manual: pilot modes, i.e. hold without a pilot; 3 return; 4 land; 5 hold;
  6 terminate; 7 disarm); data-link loss (no GCS heartbeat for ``COM_DL_LOSS_T`` s) action
  ``NAV_DLL_ACT`` (0 disabled, 1 hold, 2 return, 3 land, 5 terminate, 6 disarm).

:func:`assess` says in words what a vehicle would do and whether it would just hover forever;
:func:`check_failsafe_params` reads the parameters of every connected vehicle, reports them,
warns about hover-forever vehicles and, with ``[preflight] require_gcs_failsafe = true``, makes
them not ready (``fly`` refuses to take off).
"""
from __future__ import annotations

import asyncio
from dataclasses import dataclass

from mission.core.plan_types import PreflightPlan
from mission.flight.services import Events
from mission.flight.state import MissionState
from mission.vehicle.prearm_params import read_params

__all__ = ["FailsafeAssessment", "PARAMS", "assess", "check_failsafe_params", "report_lines"]

#: the parameters read per flavour
PARAMS = {
    "ardupilot": ("FS_GCS_ENABLE", "FS_GCS_TIMEOUT"),
    "px4": ("COM_OBL_RC_ACT", "COM_OF_LOSS_T", "NAV_DLL_ACT", "COM_DL_LOSS_T"),
}
_AP_GCS = {0: "nothing (failsafe disabled): holds its last target", 1: "RTL", 2: "RTL", 3: "SmartRTL or RTL",
           4: "SmartRTL or land", 5: "land", 6: "DO_LAND_START mission or RTL", 7: "brake or land"}
_PX4_OBL = {0: "position mode (a pilot's mode; PX4 v1.16 SIH without RC then descended and landed)", 1: "altitude mode (hold without a pilot)",
            2: "manual mode (hold without a pilot)", 3: "return", 4: "land", 5: "hold",
            6: "flight termination", 7: "disarm"}
_PX4_OBL_HOLDS = {0, 1, 2, 5}
_PX4_DLL = {0: "nothing (disabled)", 1: "hold", 2: "return", 3: "land", 5: "flight termination",
            6: "disarm"}
_PX4_DLL_ACTS = {2, 3, 5, 6}


@dataclass
class FailsafeAssessment:
    """What one vehicle does when the ground station dies.

    Attributes
    ----------
    values : dict of str to float
        The failsafe parameters read.
    missing : list of str
        Parameters the vehicle did not report.
    action : str
        In words, e.g. ``"RTL after 5 s without a ground-station heartbeat"``.
    hovers_forever : bool or None
        True when nothing brings the vehicle down (it hovers until its battery fails); None
        when the parameters could not be read.
    """

    values: dict
    missing: list
    action: str
    hovers_forever: bool | None


def _ardupilot(values: dict) -> tuple[str, bool]:
    enable = int(values["FS_GCS_ENABLE"])
    timeout = values.get("FS_GCS_TIMEOUT")
    after = f" after {timeout:g} s without a ground-station heartbeat" if timeout is not None else ""
    if enable == 0:
        return "holds its last GUIDED target (FS_GCS_ENABLE = 0: GCS failsafe disabled)", True
    return f"{_AP_GCS.get(enable, f'FS_GCS_ENABLE = {enable}')}{after}", False


def _px4(values: dict) -> tuple[str, bool]:
    obl = int(values["COM_OBL_RC_ACT"])
    dll = int(values["NAV_DLL_ACT"])
    of_t = values.get("COM_OF_LOSS_T")
    dl_t = values.get("COM_DL_LOSS_T")
    parts = [f"on offboard loss{f' ({of_t:g} s)' if of_t is not None else ''}: "
             f"{_PX4_OBL.get(obl, f'COM_OBL_RC_ACT = {obl}')}",
             f"on data-link loss{f' ({dl_t:g} s)' if dl_t is not None else ''}: "
             f"{_PX4_DLL.get(dll, f'NAV_DLL_ACT = {dll}')}"]
    hovers = obl in _PX4_OBL_HOLDS and dll not in _PX4_DLL_ACTS
    return "; ".join(parts), hovers


def assess(flavour: str, values: dict) -> FailsafeAssessment:
    """What a ``flavour`` vehicle with these parameter ``values`` does when the ground station dies."""
    names = PARAMS.get(flavour, ())
    missing = [n for n in names if values.get(n) is None]
    if not names:
        return FailsafeAssessment(dict(values), [], f"unknown ({flavour} autopilot: not checked)", None)
    key = names[0] if flavour == "ardupilot" else None
    needed = [key] if key else ["COM_OBL_RC_ACT", "NAV_DLL_ACT"]
    if any(values.get(n) is None for n in needed):
        return FailsafeAssessment(dict(values), missing, "unknown (parameters " + ", ".join(missing)
                                  + " not reported)", None)
    action, hovers = (_ardupilot if flavour == "ardupilot" else _px4)(values)
    return FailsafeAssessment(dict(values), missing, action, hovers)


async def _read_one(events: Events, sysid: int, v, timeout_s: float) -> FailsafeAssessment:
    names = PARAMS.get(v.flavour, ())
    try:
        values = await read_params(v, names, timeout_s) if names else {}
    except Exception as exc:  # noqa: BLE001 - link errors: reported as unknown
        events.event(f"vehicle {sysid}: failsafe parameters not read ({exc})", level="warning", sysid=sysid)
        values = {}
    return assess(v.flavour, values)


async def check_failsafe_params(state: MissionState, vehicles: dict, preflight: PreflightPlan, simulated: bool,
                                events: Events, timeout_s: float = 5.0) -> dict[int, FailsafeAssessment]:
    """Read, report and judge every connected vehicle's ground-station-loss failsafe.

    Each vehicle's readiness (in ``state``) gets a warning (or, with the plan's
    ``preflight.require_gcs_failsafe``, a failed ``gcs_failsafe`` check) when it would hover
    forever or its parameters could not be read. For ``swarmseek run``'s embedded mock fleet
    (``simulated``), which ends with the ground station, an unconfigured failsafe is said once, as
    what it is, and is no warning. ``vehicles``: the connected vehicles by system id.
    """
    require = preflight.require_gcs_failsafe
    sysids = sorted(vehicles)
    found = await asyncio.gather(*(_read_one(events, s, vehicles[s], timeout_s) for s in sysids))
    out = dict(zip(sysids, found))
    for sysids_, message, level, hovers in report_lines(out, require=require, simulated=simulated):
        events.event(message, level=level, sysids=sysids_, failsafe={s: out[s].values for s in sysids_},
                 hovers_forever=hovers)
    for s, a in out.items():
        bad = a.hovers_forever is not False
        r = state.readiness.get(s)
        if r is None:
            continue
        r.failsafe_params = {k: v for k, v in a.values.items() if v is not None}
        if require:
            r.checks["gcs_failsafe"] = not bad
            if bad:
                r.problems.append(f"ground-station-loss failsafe required by the plan: {a.action}")
            state.set_readiness(r, "ready" if r.ready else "not ready: " + "; ".join(r.problems))
        elif bad and not (simulated and a.hovers_forever):
            r.warnings.append(f"if the ground station dies: {a.action}")
    return out


def report_lines(found: dict[int, FailsafeAssessment], *, require: bool,
                 simulated: bool = False) -> list[tuple[list[int], str, str, bool | None]]:
    """One line per distinct behaviour, naming its vehicles (a fleet usually shares one).

    Parameters
    ----------
    found : dict of int to FailsafeAssessment
        Each vehicle's assessment, by system id.
    require : bool
        The plan requires a ground-station-loss failsafe (``[preflight] require_gcs_failsafe``):
        a vehicle without one is an error.
    simulated : bool
        The vehicles are the embedded mock fleet: mock autopilots with their autopilot's default
        parameters, gone when the ground station goes. Hovering ones get one informative line in
        the mock's words (unless the plan requires a failsafe).

    Returns
    -------
    list of (sysids, message, level, hovers_forever)
    """
    groups: dict[tuple, list[int]] = {}
    for s, a in found.items():
        groups.setdefault((a.action, a.hovers_forever), []).append(s)
    lines = []
    for (action, hovers), sysids in groups.items():
        bad = hovers is not False
        level = "info" if not bad else ("error" if require else "warning")
        if simulated and hovers and not require:
            lines.append((sysids, "simulation: the mock autopilots keep their defaults, no ground-station-loss "
                          f"failsafe: {action}. A real vehicle set up like this would hover until its "
                          "battery fails (docs/ardupilot.md, failsafe parameters)", "info", hovers))
            continue
        what = (" -- nothing brings it down: it would hover until its battery fails" if hovers
                else " -- failsafe unknown" if hovers is None else "")
        who = f"vehicle {sysids[0]}" if len(sysids) == 1 else "vehicles " + ", ".join(map(str, sysids))
        lines.append((sysids, f"{who}: if the ground station dies: {action}{what}", level, hovers))
    return lines
