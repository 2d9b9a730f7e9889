"""What the embedded mock fleet's vehicles refused (``swarmseek run``'s ``vehicle_rejections``).

Each mock autopilot counts the frames it drops (``MockVehicle.counters``, see
:class:`sitl_mock.autopilot.MockAutopilot`); :func:`vehicle_rejections` keeps the kinds that
mean "a frame was refused" (:data:`VEHICLE_REJECTION_KINDS`), per vehicle, non-zero only.
"""
from __future__ import annotations

__all__ = ["VEHICLE_REJECTION_KINDS", "vehicle_rejections", "world_errors_line"]

#: mock autopilot counters of refused frames: signing (``rx_unsigned``, ``rx_bad_signature``,
#: ``rx_replayed``, ``signing_setup_refused_armed``), damaged or foreign frames (``rx_bad_crc``,
#: ``rx_malformed``, ``rx_truncated``, ``rx_unknown_msg``, ``rx_parser_error``) and frames for
#: another system (``rx_not_for_us``)
VEHICLE_REJECTION_KINDS = ("rx_unsigned", "rx_bad_signature", "rx_replayed", "signing_setup_refused_armed",
                           "rx_bad_crc", "rx_malformed", "rx_truncated", "rx_unknown_msg",
                           "rx_parser_error", "rx_not_for_us")


def vehicle_rejections(fleet) -> dict[int, dict[str, int]]:
    """Frames each vehicle of ``fleet`` refused, by sysid then kind; vehicles that refused
    nothing are left out.

    Parameters
    ----------
    fleet : sitl_mock.fleet.MockFleet
        Its ``vehicles`` have ``sysid`` and ``counters``.
    """
    out: dict[int, dict[str, int]] = {}
    for v in fleet.vehicles:
        counters = v.counters
        kinds = {k: int(counters[k]) for k in VEHICLE_REJECTION_KINDS if counters.get(k)}
        if kinds:
            out[int(v.sysid)] = kinds
    return out


def world_errors_line(fleet) -> str | None:
    """One line telling the errors the simulated world caught and kept (``fleet.errors``, a
    traceback each: e.g. a field plug-in that failed where the probe did not look), or None.

    Parameters
    ----------
    fleet : sitl_mock.fleet.MockFleet
        Its ``errors`` are formatted tracebacks (at most its cap are kept).
    """
    errors = list(fleet.errors)
    if not errors:
        return None
    last = [line for line in errors[0].strip().splitlines() if line.strip()][-1].strip()
    return f"the simulated world caught {len(errors)} error(s) (at most the first ones are kept); the first: {last}"
