"""Live progress display: a table redrawn in place on a terminal, plain lines otherwise.

The display renders the coordinator's state snapshot (the same dict published on
``swarmseek/<fleet>/mission/state``, see ``docs/mission.md``): phase, per-vehicle mode, armed,
altitude, link age and setpoint rate; centre, gradient and distance flown; the source estimate
with its 95 % region and what that region is; the readings and MAVLink frames rejected.
"""
from __future__ import annotations

import json
import sys
import time
from typing import IO

from mission.telemetry.link_report import format_rejections

__all__ = ["Display", "format_table", "format_line", "format_summary", "format_geodetic", "report_result"]


def _vec(v, fmt="{:7.2f}") -> str:
    if v is None:
        return "-"
    return "(" + ", ".join(fmt.format(float(x)) for x in v) + ")"


def _num(v, fmt="{:.2f}") -> str:
    return "-" if v is None else fmt.format(float(v))


def _region(d: dict) -> str:
    """``95 % region 0.42 m`` of a snapshot or summary; ``95 % region none`` when the estimate has none,
    ``-`` before any estimate."""
    if d.get("estimate_enu") is None:
        return "95 % region -"
    r = d.get("estimate_region95_m")
    return "95 % region none" if r is None else f"95 % region {float(r):.2f} m"


def format_geodetic(geo: dict | None) -> str:
    """``lat 45.1900123, lon 5.7200456, alt 242.3 m AMSL`` (``-`` when unknown).

    Seven decimals of a degree: about 1 cm of latitude, finer than any estimate.
    """
    if not geo:
        return "-"
    return (f"lat {float(geo['lat_deg']):.7f}, lon {float(geo['lon_deg']):.7f}, "
            f"alt {float(geo['alt_m']):.1f} m AMSL")


def format_table(state: dict) -> list[str]:
    """The lines of the live table for one state snapshot."""
    lines = [
        f"swarmseek  fleet {state.get('fleet', '?')}  phase {state.get('phase', '?').upper():9s}"
        f"  t {_num(state.get('elapsed_s'), '{:7.1f}')} s  iteration {state.get('iteration', 0)}",
        f"centre {_vec(state.get('centre_enu'))} m   gradient {_vec(state.get('gradient'), '{:+.2e}')}",
        f"estimate {_vec(state.get('estimate_enu'))} m  {_region(state)}  spread {_num(state.get('spread_m'))} m"
        f"   flown {_num(state.get('distance_flown_m'), '{:.1f}')} m",
    ]
    if state.get("estimate_basis"):
        lines.append(f"  basis: {state['estimate_basis']}")
    if state.get("estimate_geodetic"):
        lines.append(f"estimate {format_geodetic(state['estimate_geodetic'])}")
    rd = state.get("readings") or {}
    rejected = {k: v for k, v in (rd.get("rejected") or {}).items() if v}
    lines.append(f"readings accepted {rd.get('accepted', 0)}  rejected {rejected or 0}")
    unknown = state.get("unknown_sysids") or []
    lines.append(f"MAVLink rejected {format_rejections(state.get('link_rejections'))}"
                 + (f"  unknown sysids {unknown}" if unknown else ""))
    lines.extend(_control_lines(state.get("control")))
    lines.append(f"{'sysid':>5} {'id':10} {'flavour':9} {'mode':12} {'armed':5} {'alt_m':>7} "
                 f"{'link_s':>6} {'sp_hz':>6}  status")
    for v in state.get("vehicles", []):
        lines.append(
            f"{v.get('sysid', '?'):>5} {str(v.get('id', ''))[:10]:10} {str(v.get('flavour', ''))[:9]:9} "
            f"{str(v.get('mode', ''))[:12]:12} {('yes' if v.get('armed') else 'no'):5} "
            f"{_num(v.get('relative_alt_m'), '{:7.2f}'):>7} {_num(v.get('link_age_s'), '{:6.2f}'):>6} "
            f"{_num(v.get('setpoint_rate_hz'), '{:6.1f}'):>6}  {v.get('status', '')}")
    return lines


def _control_lines(control) -> list[str]:
    """The operator's commands in force (``swarmseek ctl``, terminal keys), if any."""
    if not control or not (control.get("paused") or control.get("stop")):
        return []
    if control.get("stop"):
        return [f"OPERATOR {str(control['stop']).upper()} ordered: the mission is ending"]
    held = "holding the formation" if control.get("holding") else "the formation holds at the end of this iteration"
    return [f"PAUSED by {control.get('paused_by')}: {held} (continue: key c, or swarmseek ctl FLEET continue)"]


def format_line(state: dict) -> str:
    """One plain progress line for one state snapshot."""
    armed = sum(1 for v in state.get("vehicles", []) if v.get("armed"))
    rejected = state.get("link_rejections") or {}
    return (f"[{_num(state.get('elapsed_s'), '{:7.1f}')} s] {state.get('phase', '?'):8s} "
            f"k={state.get('iteration', 0):<4d} centre={_vec(state.get('centre_enu'), '{:.2f}')} "
            f"|grad|={_num(state.get('gradient_norm'), '{:.2e}')} "
            + (f"estimate={_vec(state['estimate_enu'], '{:.2f}')} {_region(state).replace('95 % region ', 'r95=')} "
               if state.get("estimate_enu") is not None else "")
            + f"flown={_num(state.get('distance_flown_m'), '{:.1f}')} m armed={armed}/"
            f"{len(state.get('vehicles', []))}"
            + (f" mavlink_rejected={format_rejections(rejected)}" if any(rejected.values()) else "")
            + "".join(f" [{line.split(':')[0].replace('OPERATOR', 'operator')}]"
                      for line in _control_lines(state.get("control"))))


def format_summary(summary: dict) -> list[str]:
    """Human-readable lines of the end-of-mission summary."""
    lines = [f"mission {summary.get('outcome', '?')}: {summary.get('message', '')}"]
    if summary.get("estimate_enu") is not None:
        lines.append(f"  estimated source {_vec(summary['estimate_enu'], '{:.2f}')} m, {_region(summary)} "
                     f"(spread {_num(summary.get('spread_m'))} m) after {summary.get('iterations', 0)} iterations")
        if summary.get("estimate_basis"):
            lines.append(f"                   basis: {summary['estimate_basis']}")
        if summary.get("estimate_geodetic"):
            lines.append(f"                   {format_geodetic(summary['estimate_geodetic'])}")
    if summary.get("true_source_enu") is not None:
        lines.append(f"  true source      {_vec(summary['true_source_enu'], '{:.2f}')} m, "
                     f"error {_num(summary.get('error_m'))} m")
        if summary.get("true_source_geodetic"):
            lines.append(f"                   {format_geodetic(summary['true_source_geodetic'])}")
    lines.append(f"  mission time {_num(summary.get('mission_time_s'), '{:.1f}')} s, seek time "
                 f"{_num(summary.get('seek_time_s'), '{:.1f}')} s, distance flown (centre) "
                 f"{_num(summary.get('distance_flown_m'), '{:.1f}')} m")
    for loss in summary.get("lost") or ():
        latency = loss.get("latency_s")
        detected = f", detected after {latency:.2f} s" if isinstance(latency, (int, float)) else ""
        lines.append(f"  lost vehicle {loss.get('sysid')} in {loss.get('phase', '?')}: "
                     f"{loss.get('reason', '?')} ({loss.get('detail', '')}){detected}")
    if any((summary.get("link_rejections") or {}).values()):
        lines.append(f"  MAVLink frames rejected by the ground station: {format_rejections(summary['link_rejections'])}")
    if summary.get("unknown_sysids"):
        lines.append(f"  MAVLink system ids heard, not in the plan (ignored): {summary['unknown_sysids']}")
    for sysid, counts in (summary.get("vehicle_rejections") or {}).items():
        if any(counts.values()):
            lines.append(f"  frames rejected by vehicle {sysid}: {format_rejections(counts)}")
    if summary.get("still_armed"):
        lines.append(f"  STILL ARMED at the end: vehicles {[e.get('sysid') for e in summary['still_armed']]} "
                     "(landed or landing; disarm them before approaching)")
    for x in summary.get("retired") or ():
        lines.append(f"  sensor of vehicle {x.get('sysid')} retired after iteration {x.get('iteration')} "
                     f"({x.get('reason')}, {_num(x.get('ratio'), '{:.1f}')}x the median noise): parked at the centre")
    return lines


class Display:
    """Shows the coordinator's progress.

    Parameters
    ----------
    stream : file, optional
        Default ``sys.stdout``.
    tty : bool, optional
        Redraw a table in place (default: ``stream.isatty()``).
    quiet : bool
        Show nothing (e.g. with ``--json``).
    min_interval_s : float
        Plain lines: at most one per this many wall seconds, plus one per phase change.
    """

    def __init__(self, stream: IO[str] | None = None, tty: bool | None = None, quiet: bool = False,
                 min_interval_s: float = 1.0):
        self.stream = stream if stream is not None else sys.stdout
        if tty is None:
            try:
                tty = self.stream.isatty()
            except (AttributeError, ValueError):
                tty = False
        self.tty = bool(tty)
        self.quiet = quiet
        self.min_interval_s = float(min_interval_s)
        self._drawn_lines = 0
        self._last_phase = None
        self._last_line_s = -1e9

    def update(self, state: dict) -> None:
        """Render one snapshot (table in place, or a plain line when due)."""
        if self.quiet:
            return
        if self.tty:
            lines = format_table(state)
            out = []
            if self._drawn_lines:
                out.append(f"\x1b[{self._drawn_lines}F")
            out.extend("\x1b[2K" + line + "\n" for line in lines)
            if self._drawn_lines > len(lines):
                out.extend("\x1b[2K\n" for _ in range(self._drawn_lines - len(lines)))
            self.stream.write("".join(out))
            self.stream.flush()
            self._drawn_lines = max(self._drawn_lines, len(lines))
            self._last_phase = state.get("phase")
            return
        now = time.monotonic()
        phase = state.get("phase")
        if phase != self._last_phase or now - self._last_line_s >= self.min_interval_s:
            self._last_phase = phase
            self._last_line_s = now
            self.stream.write(format_line(state) + "\n")
            self.stream.flush()

    def message(self, text: str) -> None:
        """An event line (printed above the table on a terminal)."""
        if self.quiet:
            return
        if self.tty and self._drawn_lines:
            self.stream.write(f"\x1b[{self._drawn_lines}F\x1b[0J")
            self._drawn_lines = 0
        self.stream.write(text + "\n")
        self.stream.flush()

    def summary(self, summary: dict) -> None:
        """Print the end-of-mission summary."""
        if self.quiet:
            return
        for line in format_summary(summary):
            self.stream.write(line + "\n")
        self.stream.flush()


def report_result(result, display: "Display", as_json: bool) -> int:
    """Print a finished mission's summary (JSON with ``as_json``) and return its exit status
    (:attr:`mission.flight.result.MissionResult.exit_status`)."""
    summary = result.to_json()
    if as_json:
        print(json.dumps(summary, indent=2))
    else:
        display.summary(summary)
    return result.exit_status
