"""A client that closes normally is no news: amqtt 0.12.1 logs a browser tab's reload (websocket
close 1001, "going away") as an unhandled exception, and every message still on its way to that
tab as a failed task with a traceback. An operator's terminal should not look like a crash."""

from __future__ import annotations

import logging
import re

from websockets.exceptions import ConnectionClosed

# What delivering to a client that has gone raises: its socket reset or closed, its websocket
# closed (normally or not). Nothing to deliver to; not an error of the broker's.
GONE: tuple[type[BaseException], ...] = (ConnectionError, ConnectionClosed)

# amqtt's own words for those, from its protocol handler (no exception attached to the record).
_NORMAL_CLOSE = re.compile(r"Unhandled exception.*\b100[01] \((OK|going away)\)")
HANDLER_LOGGER = "amqtt.mqtt.protocol.handler"
# amqtt's line for a CONNECT gridfleet's broker refused: it has logged why already (rate-limited).
_REFUSED = re.compile(r"Failed to initialize client session: .* not authorized$")
BROKER_LOGGER = "amqtt.broker"


class NormalCloses(logging.Filter):
    """Drops amqtt's records of websocket clients that closed normally (1000 or 1001)."""

    def filter(self, record: logging.LogRecord) -> bool:
        """False for a normal close, which then goes unlogged."""
        return _NORMAL_CLOSE.search(record.getMessage()) is None


class RefusedConnects(logging.Filter):
    """Drops amqtt's record of each refused CONNECT (a flood of them would flood the log)."""

    def filter(self, record: logging.LogRecord) -> bool:
        """False for a refused CONNECT."""
        return _REFUSED.search(record.getMessage()) is None


def quiet_normal_closes() -> None:
    """Install the filters on amqtt's loggers, once."""
    for name, kind in ((HANDLER_LOGGER, NormalCloses), (BROKER_LOGGER, RefusedConnects)):
        logger = logging.getLogger(name)
        if not any(isinstance(f, kind) for f in logger.filters):
            logger.addFilter(kind())
