"""Webhook URLs that cannot be turned inward: resolved, and refused when an address they
name is not on the public internet, unless an administrator allowed its network.

A webhook URL is chosen by whoever manages a site's alerts, and the worker calls it from
inside the deployment: pointed at 127.0.0.1, the cloud's metadata service (169.254.169.254)
or a private network, it would make the server call what only the server can reach. The
URL is checked when the webhook is saved and again at every call; the call then goes to
the very address that was checked (the host name still sent in `Host` and as TLS SNI), so
a name that resolves elsewhere between check and call (DNS rebinding) reaches nothing new.
Any spelling of an address (0x7f000001, 2130706433, 0177.1, ::ffff:127.0.0.1) is judged by
what it resolves to.
"""

from __future__ import annotations

import ipaddress
import socket
from collections.abc import Iterable
from dataclasses import dataclass
from urllib.parse import urlsplit, urlunsplit

IpAddress = ipaddress.IPv4Address | ipaddress.IPv6Address
Network = ipaddress.IPv4Network | ipaddress.IPv6Network
# NAT64 (RFC 6052): an IPv4 address spelled as IPv6, judged as the IPv4 address it holds.
_NAT64 = ipaddress.ip_network("64:ff9b::/96")


class UrlRefused(ValueError):
    """A webhook URL that may not be called; the message says why."""


@dataclass(frozen=True)
class Target:
    """Where to send a checked URL: the URL with the address in place of the host name,
    and the name for the `Host` header and TLS (SNI and the certificate's name)."""

    url: str
    host_header: str
    server_name: str
    address: IpAddress


def parse_networks(values: Iterable[str]) -> list[Network]:
    """Networks of the allow-list setting (CIDR); ValueError naming one that is not."""
    networks = []
    for value in values:
        try:
            networks.append(ipaddress.ip_network(value.strip(), strict=False))
        except ValueError:
            raise ValueError(f"{value!r} is not a network such as 10.0.0.0/8 or fd00::/8") from None
    return networks


def check_url_form(url: str) -> None:
    """What can be said of the URL without resolving it: http(s), a host, no credentials."""
    try:
        parts = urlsplit(url)
        parts.port  # noqa: B018 (raises on a port that is not a number in range)
    except ValueError as exc:
        raise UrlRefused(f"{url!r} is not a URL: {exc}") from None
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise UrlRefused(f"{url!r} is not an http(s) URL")
    if "@" in parts.netloc:
        raise UrlRefused(
            "a webhook URL may not carry a user name or password; the calls are signed "
            "(X-Slidewatch-Signature) instead"
        )
    if any(ord(c) < 33 or ord(c) == 127 for c in url):
        raise UrlRefused("a webhook URL may not contain spaces or control characters")


def resolve_target(url: str, allowed: list[Network]) -> Target:
    """Check `url` and resolve it to the address a call must go to; UrlRefused if any
    address its host resolves to is not public (nor in `allowed`)."""
    check_url_form(url)
    parts = urlsplit(url)
    host = parts.hostname or ""
    port = parts.port or (443 if parts.scheme == "https" else 80)
    try:
        found = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as exc:
        raise UrlRefused(
            f"the host {host!r} of the webhook URL cannot be resolved: {exc}"
        ) from None
    addresses = [ipaddress.ip_address(str(info[4][0]).split("%")[0]) for info in found]
    for address in addresses:
        problem = _why_refused(address, allowed)
        if problem:
            raise UrlRefused(
                f"the webhook URL's host {host!r} resolves to {address}, {problem}; calls "
                "go only to public addresses (an administrator may allow a network with "
                "SLIDEWATCH_WEBHOOK_ALLOWED_NETWORKS)"
            )
    address = addresses[0]
    literal = f"[{address}]" if address.version == 6 else str(address)
    netloc = f"{literal}:{parts.port}" if parts.port else literal
    return Target(
        url=urlunsplit((parts.scheme, netloc, parts.path, parts.query, "")),
        host_header=parts.netloc,
        server_name=host,
        address=address,
    )


def _why_refused(address: IpAddress, allowed: list[Network]) -> str | None:
    judged = _embedded_ipv4(address) or address
    if any(judged in network or address in network for network in allowed):
        return None
    for test, what in (
        ("is_unspecified", "an unspecified address"),
        ("is_loopback", "a loopback address"),
        ("is_link_local", "a link-local address"),
        ("is_multicast", "a multicast address"),
        ("is_private", "a private address"),
        ("is_reserved", "a reserved address"),
    ):
        if getattr(judged, test):
            return what
    if not judged.is_global:
        return "not a public address"
    return None


def _embedded_ipv4(address: IpAddress) -> ipaddress.IPv4Address | None:
    """The IPv4 address an IPv6 one stands for: IPv4-mapped (::ffff:a.b.c.d), NAT64."""
    if address.version != 6:
        return None
    if address.ipv4_mapped is not None:  # type: ignore[union-attr]
        return address.ipv4_mapped  # type: ignore[union-attr]
    if address in _NAT64:
        return ipaddress.IPv4Address(int(address) & 0xFFFFFFFF)
    return None
