"""Which web pages may open the broker's websocket listener (pure).

A browser lets any page it shows open a websocket to any address, loopback included, and sends
the page's origin with it. Without a check, a page from another site, open in the operator's
browser, could connect to the no-accounts default on 127.0.0.1 and release the stop. So:

- without accounts, the Host the browser asked for must name this machine by an IP address or
  `localhost` (or a name given in `ws_origins`): a DNS-rebinding page asks for its own name and
  is refused;
- a page's origin must be on that same host (the dashboard, on another port of it), or be one of
  `ws_origins`.

Clients that are not browsers send no Origin header; they are let in (they can use the TCP
listener anyway).
"""

from __future__ import annotations

from urllib.parse import urlsplit

from gridfleet.config import host_of, is_loopback, names_this_machine


def refusal(
    host: str | None,
    origin: str | None,
    extra_origins: tuple[str, ...] = (),
    *,
    accounts: bool = False,
) -> str | None:
    """None when a websocket with these Host and Origin headers may connect; else why not.

    With `accounts`, any host name is let in (people reach a LAN broker by the machine's name,
    and a rebinding page would still need a password); without, only addresses and `localhost`.
    """
    if origin is None:
        return None
    allowed = {o.rstrip("/").lower() for o in extra_origins}
    if origin.rstrip("/").lower() in allowed:
        return None
    asked = host_of(host or "")
    named = {host_of(urlsplit(o).netloc) for o in allowed}  # configured pages' host names
    if not accounts and not (names_this_machine(host or "") or asked in named):
        return f"Host {host!r} names no address of this machine (a DNS-rebinding page?)"
    page = host_of(urlsplit(origin).netloc)
    if page != asked and not (is_loopback(page) and is_loopback(asked)):
        return f"a page from {origin} is not the dashboard's (on {asked})"
    return None
