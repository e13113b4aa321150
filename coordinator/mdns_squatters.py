"""A listener that names the other mDNS responders answering for the coordinator's own instance name.

Imported only by a coordinator that advertises (:mod:`coordinator.mdns` loads it when it starts), since
its base class is zeroconf's and ``--no-mdns`` starts without zeroconf.
"""
from __future__ import annotations

import logging

from zeroconf import DNSService, RecordUpdateListener

log = logging.getLogger("coordinator.mdns")

#: how many distinct foreign targets are remembered (and logged) at most
MAX_LOGGED = 64


class Squatters(RecordUpdateListener):
    """Logs (once each) the other targets that responses name for this coordinator's own instance name."""

    def __init__(self, name: str, server: str, port: int):
        super().__init__()
        self.name, self.own = name.lower(), (server.lower(), port)
        self.seen: set[tuple[str, int]] = set()

    def async_update_records(self, zc, now: float, records) -> None:
        for update in records:
            rec = update.new
            if isinstance(rec, DNSService) and rec.name.lower() == self.name and rec.ttl:
                target = (rec.server.lower(), rec.port)
                if target != self.own and target not in self.seen and len(self.seen) < MAX_LOGGED:
                    self.seen.add(target)
                    log.warning("another mDNS responder answers for this coordinator's name %s, pointing at %s "
                                "port %d (an advertiser that did not probe for the name); nodes and operators "
                                "join only the coordinator that proves the rig token", rec.name, rec.server,
                                rec.port)
