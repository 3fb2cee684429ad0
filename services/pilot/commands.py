"""What the control thread decides, once per tick, of what came on pilot/route and
pilot/cmd (read and checked by the inbox) and on steering/estop: a route taken or refused,
start, stop. An estop stops the pilot at the next tick and refuses every start that came
before it (a flag and a number, not a queued request: no flood delays it)."""
from __future__ import annotations

import logging
from collections.abc import Callable

from viena.common import clock
from viena.common.health import Health
from viena.services.pilot.inbox import ACCEPTED, ROUTE, Inbox, Request
from viena.services.pilot.model.pilot import IDLE, Pilot
from viena.services.pilot.model.route import RouteError
from viena.services.pilot.steering_link import SteeringLink


class Commands:
    """Decides the requests the inbox read and the estops put (see the module's docstring);
    `on_route` is called when a route is taken (to publish it at once)."""

    def __init__(self, pilot: Pilot, inbox: Inbox, link: SteeringLink, health: Health, log: logging.Logger,
                 on_route: Callable[[], None]):
        self.pilot, self.inbox, self.link, self.health, self.log = pilot, inbox, link, health, log
        self._on_route = on_route
        self._estop = clock.Event()                    # an estop put came: stop at the next tick
        self._estop_number = 0                         # and refuse a start that came before it

    def on_estop(self) -> None:
        """From a zenoh callback: never blocks, never fails, whatever else is queued."""
        self._estop_number = self.inbox.number()
        self._estop.set()

    def decide(self) -> None:
        """The requests read since the last tick, then an estop put since (a query's answers
        end when this returns and its last reference goes: not after the arm that a start
        leads to)."""
        for request in self.inbox.take():
            try:
                self._handle(request)
            finally:
                self.inbox.decided()
        if self._estop.is_set():
            self._estop.clear()
            if self.pilot.mode == "following":
                self.pilot.stop("estop")
                self.log.warning("estop: stopped")

    def _handle(self, request: Request) -> None:
        if request.kind == ROUTE:
            self._take_route(request)
        elif request.value == "start":
            self._start(request)
        else:
            self.pilot.stop("stop command")
            self.link.give_back_lease()
            request.answer({"status": ACCEPTED, "mode": self.pilot.mode})

    def _take_route(self, request: Request) -> None:
        route = request.value
        try:
            self.pilot.set_route(route)
        except RouteError as exc:
            self.inbox.refuse(request, str(exc))
            return
        self.health.count("route")
        self._on_route()                               # publish it now
        self.log.info("route: %d checkpoints, %.0f m (%s)", len(route), route.length_m, route.form)
        if self.pilot.mode == IDLE:
            request.answer_accepted()
        else:
            request.answer({"status": ACCEPTED, "route": route.to_geojson(), "mode": self.pilot.mode})

    def _start(self, request: Request) -> None:
        if request.number < self._estop_number:
            self.inbox.refuse(request, "an estop came after this start")
            return
        why = self.pilot.start(clock.time_ns())
        if why is not None:
            self.inbox.refuse(request, why)
            return
        self.log.info("start: following")
        request.answer({"status": ACCEPTED, "mode": self.pilot.mode})
