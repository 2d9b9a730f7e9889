"""A coordinator's control side without a mission: the plan's zenoh session and a control channel.

Tests of ``swarmseek ctl`` against access control and TLS need something that answers commands
the way the coordinator does, with the plan's own session (its logins, certificates and access
control). :class:`ControlPeer` runs a :class:`~mission.telemetry.control_channel.ControlChannel`
on its own event loop in a thread, records every command it receives and accepts it. ``close``
stops the channel, closes the loop (its self-pipe sockets with it) and the session, so nothing is
left for the garbage collector to warn about in a later test.
"""
from __future__ import annotations

import asyncio
import threading

from mission.telemetry.control_channel import ControlChannel


class ControlPeer(threading.Thread):
    """The coordinator's zenoh side: the plan's session and its control channel on an event loop.

    Parameters
    ----------
    plan : mission.core.plan_types.MissionPlan
        The plan whose ``zenoh`` section opens the session and whose ``fleet`` names the keys.
    start_timeout_s : float
        How long to wait for the channel to be declared before failing.
    """

    def __init__(self, plan, start_timeout_s: float = 20.0):
        super().__init__(daemon=True)
        import zenoh

        self.session = zenoh.open(plan.zenoh.to_config())
        self.commands: list[tuple[str, str]] = []
        self.channel = ControlChannel(self.session, plan.fleet, self._submit, poll_s=0.02)
        self.loop = asyncio.new_event_loop()
        self._started = threading.Event()
        self._stop_event: asyncio.Event | None = None
        self.start()
        if not self._started.wait(start_timeout_s):
            self.close()
            raise AssertionError(f"control channel did not start within {start_timeout_s} s")

    def _submit(self, command, sender):
        self.commands.append((command, sender))
        return {"command": command, "sender": sender, "accepted": True, "reason": "ok", "phase": "seek"}

    def run(self):
        asyncio.set_event_loop(self.loop)
        try:
            self.loop.run_until_complete(self._main())
        finally:
            self.loop.run_until_complete(self.loop.shutdown_asyncgens())
            self.loop.close()

    async def _main(self):
        self.channel.start()
        self._stop_event = asyncio.Event()
        self._started.set()
        await self._stop_event.wait()
        await self.channel.stop()

    def close(self):
        """Stop the channel, close the loop and the session (idempotent)."""
        if self._stop_event is not None and not self.loop.is_closed():
            self.loop.call_soon_threadsafe(self._stop_event.set)
        self.join(timeout=10)
        self.session.close()
