"""Which web pages may open the broker's websocket listener (pure).

A browser lets any page it shows open a websocket to any address, loopback included, and sends
the page's origin with it. Without a check, a page from another site, open in the operator's
browser, could connect to the no-accounts default on 127.0.0.1 and release the stop. So:

- without accounts, a page's origin must be one of `ws_origins`, exactly (scheme, host and
  port): the dashboard's, which `gridfleet up` passes (`dashboard_origins`). Any other page of
  this machine is refused too (as found: one from `http://localhost:<another port>` released the
  operator's stop and queued jobs). A page that is not one of them is refused the more plainly
  when the Host the browser asked for names this machine by no IP address, `localhost` or
  configured origin's name (a DNS-rebinding page asks for its own name);
- with accounts, a page on the host the browser reached the broker at (loopback names count as
  one host) or one of `ws_origins` gets in: it still needs a password.

Clients that are not browsers send no Origin header, or (paho) the listener's own address as
one, which no page can have (the broker serves none): they are let in (they can use the TCP
listener anyway).
"""

from __future__ import annotations

from collections.abc import Iterable
from urllib.parse import urlsplit

from gridfleet.config import host_of, is_loopback, names_this_machine

DEFAULT_DASHBOARD_PORT = 5000  # `gridfleet dashboard`'s and `gridfleet up`'s
LOCAL_NAMES = ("127.0.0.1", "localhost")  # what a person types to reach a dashboard here
_DEFAULT_PORTS = {"http": 80, "https": 443}


def dashboard_origins(
    port: int = DEFAULT_DASHBOARD_PORT, tls: bool = False, hosts: Iterable[str] = LOCAL_NAMES
) -> tuple[str, ...]:
    """The origins of a dashboard served on `port` (https with `tls`), by each of `hosts`."""
    scheme = "https" if tls else "http"
    return tuple(_canonical(f"{scheme}://{_bracketed(h)}:{port}") for h in hosts)


def _bracketed(host: str) -> str:
    """`host` as a URL carries it (an IPv6 address in brackets)."""
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


def _canonical(origin: str) -> str:
    """`origin` as a browser sends it: lowercase, no trailing `/`, no default port."""
    parts = urlsplit(origin.strip().rstrip("/").lower())
    try:
        port = parts.port
    except ValueError:  # not a port: compared as written
        return origin.strip().rstrip("/").lower()
    host = _bracketed(parts.hostname or "")
    if port is None or port == _DEFAULT_PORTS.get(parts.scheme):
        return f"{parts.scheme}://{host}"
    return f"{parts.scheme}://{host}:{port}"


def refusal(
    host: str | None,
    origin: str | None,
    extra_origins: tuple[str, ...] = (),
    *,
    accounts: bool = False,
) -> str | None:
    """None when a websocket with these Host and Origin headers may connect; else why not.

    With `accounts`, any host name is let in (people reach a LAN broker by the machine's name,
    and a rebinding page would still need a password), and pages on that host; without, only
    addresses and `localhost`, and only the pages of `extra_origins`.
    """
    if origin is None:
        return None
    allowed = {_canonical(o) for o in extra_origins}
    if _canonical(origin) in allowed:
        return None
    asked = host_of(host or "")
    named = {host_of(urlsplit(o).netloc) for o in allowed}  # configured pages' host names
    if not accounts and not (names_this_machine(host or "") or asked in named):
        return f"Host {host!r} names no address of this machine (a DNS-rebinding page?)"
    if _canonical(origin) in {_canonical(f"{s}://{host}") for s in _DEFAULT_PORTS}:
        return None  # the listener's own: no page has it (paho, a client, sends it as Origin)
    if not accounts:
        pages = ", ".join(sorted(allowed)) or "none given"
        return f"a page from {origin} is not the dashboard's ({pages}; --ws-origin adds one)"
    page = host_of(urlsplit(origin).netloc)
    if page != asked and not (is_loopback(page) and is_loopback(asked)):
        return f"a page from {origin} is not the dashboard's (on {asked})"
    return None
