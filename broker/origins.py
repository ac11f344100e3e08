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

import ipaddress
from urllib.parse import urlsplit


def _hostname(authority: str) -> str:
    """`127.0.0.1` of `127.0.0.1:9001`, `::1` of `[::1]:9001`, lowercased."""
    return (urlsplit(f"//{authority}").hostname or "").lower()


def _is_address(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


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
    asked = _hostname(host or "")
    names = {"localhost", *(_hostname(urlsplit(o).netloc) for o in allowed)}
    if not accounts and not (_is_address(asked) or asked in names):
        return f"Host {host!r} names no address of this machine (a DNS-rebinding page?)"
    page = (urlsplit(origin).hostname or "").lower()
    if page != asked and not (_is_loopback(page) and _is_loopback(asked)):
        return f"a page from {origin} is not the dashboard's (on {asked})"
    return None


def _is_loopback(name: str) -> bool:
    """Whether `name` is this machine by its loopback name or address."""
    return name == "localhost" or (_is_address(name) and ipaddress.ip_address(name).is_loopback)
