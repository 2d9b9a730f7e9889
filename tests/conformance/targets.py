"""Where a conformance session runs: one mock vehicle or one real SITL instance.

:func:`on_mock` starts a one-vehicle :class:`sitl_mock.fleet.MockFleet` of a personality
(PX4 style: the session listens on UDP as on PX4's API link; ArduPilot style: TCP as on SERIAL0)
on free ports, runs a session ``run(uri, sysid, wall_scale)`` against it and stops it;
:func:`on_sitl` does the same with one real SITL instance started through
:mod:`mission.sim.sitl_fleet`. :func:`observe_mock` and :func:`observe_sitl` run the
conformance script (:func:`~conformance.script.run_script`) there; the failsafe sessions
(:mod:`conformance.ap_failsafes`, :mod:`conformance.px4_failsafes`) run theirs.
"""
from __future__ import annotations

from typing import Callable

from tests.conformance.client import Observation
from tests.conformance.script import run_script
from mission.sim.embedded import free_port_block

__all__ = ["MOCK_SPEEDUP", "SITL_SPEEDUP", "mock_param_names", "observe_mock", "observe_sitl", "on_mock", "on_sitl"]

#: a session against one vehicle: ``run(uri, sysid, wall_scale) -> Observation``
Session = Callable[[str, int, float], Observation]

#: The mock runs this much faster than real time (its SimClock; telemetry carries its time).
MOCK_SPEEDUP = 4.0
#: Real SITL speed-up: ArduCopter's --speedup is sound (its scheduler runs in simulated time);
#: PX4 SIH keeps lock-step real time (PX4_SIM_SPEED_FACTOR also scales PX4's own timeouts,
#: but on a loaded 2-core host it lags behind and the estimator then complains), so 1.
SITL_SPEEDUP = {"ardupilot": 4.0, "px4": 1.0}


def mock_param_names(flavour: str) -> list[str]:
    """Names in the mock's parameter table of ``flavour`` (mock-only ``SIM_*`` names left out)."""
    from sitl_mock.ap_params import ardupilot_param_specs, px4_param_specs
    from sitl_mock.dynamics_params import DynamicsParams
    specs = (ardupilot_param_specs if flavour == "ardupilot" else px4_param_specs)(1, DynamicsParams())
    return [s.name for s in specs if not s.name.startswith("SIM_")]


def on_mock(flavour: str, speedup: float, run: Session) -> Observation:
    """``run`` against one mock vehicle of personality ``flavour`` (its clock ``speedup`` times real
    time; the session's timeouts unscaled)."""
    import sitl_mock.clock as clock_mod
    import sitl_mock.fleet as fleet_mod
    base = free_port_block(30, kinds=("udp", "tcp"))
    fleet = fleet_mod.MockFleet(n=1, personality=flavour, clock=clock_mod.SimClock(speedup),
                                udp_base_port=base, udp_bind_base_port=base + 10, tcp_base_port=base + 20,
                                zenoh=False)
    fleet.start()
    try:
        mv = fleet.vehicles[0]
        uri = f"udpin:127.0.0.1:{mv.udp_send_port}" if flavour == "px4" else f"tcp:127.0.0.1:{mv.tcp_port}"
        return run(uri, mv.sysid, 1.0)
    finally:
        fleet.stop()


def on_sitl(flavour: str, speedup: float, run: Session, wall_scale: float = 3.0) -> Observation:
    """``run`` against one real SITL instance of ``flavour`` (found through its variable), its
    timeouts ``wall_scale`` times longer."""
    from mission.sim.sitl_fleet import SitlFleet, SitlFleetConfig
    cfg = SitlFleetConfig(flavour=flavour, n=1, speedup=speedup, ready_timeout_s=180.0).free()
    with SitlFleet(cfg) as fleet:
        v = fleet.vehicles[0]
        return run(v.connection, v.sysid, wall_scale)


def _script(flavour: str) -> Session:
    def run(uri: str, sysid: int, wall_scale: float) -> Observation:
        return run_script(uri, sysid, flavour, param_names=mock_param_names(flavour), wall_scale=wall_scale)
    return run


def observe_mock(flavour: str, *, speedup: float = MOCK_SPEEDUP) -> Observation:
    """Run the script against one mock vehicle of personality ``flavour``."""
    return on_mock(flavour, speedup, _script(flavour))


def observe_sitl(flavour: str, *, speedup: float | None = None, wall_scale: float = 3.0) -> Observation:
    """Run the script against one real SITL instance of ``flavour`` (found through its variable)."""
    return on_sitl(flavour, speedup or SITL_SPEEDUP[flavour], _script(flavour), wall_scale)
