"""A controller endpoint, parsed and checked once for every caller.

``compd check``, ``compd run`` (the config's ``[controller] endpoint``),
``compd sim --drive URL`` and every driver's constructor go through
`parse_endpoint`, so that what one of them accepts the others accept too, and
what one refuses they all refuse, with the same one-line reason:

* **credentials**: any ``@`` after the scheme marks a user name or password
  (the *last* ``@`` ends it, so a password written raw with ``/``, ``?``,
  ``#`` or ``@`` in it is still seen as one: ``opc.tcp://u:SE/CR@host``, and
  the typo ``opc.tcp:///u:SECRET@host``). It is refused: credentials belong
  in ``password_file`` / ``password_env``. The message shows the URL with
  the whole userinfo replaced by ``***`` (`redact_endpoint`).
* **port**: ASCII digits, 1..65535 (``:99999``, ``:0``, ``:abc``, ``:``
  refused); the protocol's default port when there is none.
* **path, query, fragment**: only OPC UA has a path (``/freeopcua/server/``);
  no protocol has a query or a fragment. A bare trailing ``/`` is allowed.
* **host**: an IPv4 address, an IPv6 address in brackets, or a name by the
  ASCII rules of DNS (RFC 1035/1123): labels of letters, digits, ``-`` (and
  ``_``, as Windows machine names have), 1..63 characters, not starting or
  ending with ``-``, the whole at most 253. A non-ASCII name is turned into
  its IDNA (punycode) form first; one that cannot be is refused. An IPv4
  address has one spelling, the dotted quad (``127.0.0.1``): a host made of
  numbers only, in any other form the C resolver reads as an address
  (``127.1``, ``0177.0.0.1``, ``0x7f000001``, ``0x0a.0x0.0x0.0x1``), is
  refused with the address it would reach (`numeric_host_reason`, also
  applied to the hosts compd listens on).
* no space or control character anywhere.

Pure string work: no I/O, no name resolution.
"""

from __future__ import annotations

import contextlib
import ipaddress
import re
from dataclasses import dataclass

from drivers.protocols import PROTOCOLS, ProtocolSpec

__all__ = ["Endpoint", "EndpointError", "credentials_reason", "endpoint_of",
           "numeric_host_reason", "parse_endpoint", "redact_endpoint", "userinfo"]

_SCHEME = re.compile(r"[A-Za-z][A-Za-z0-9+.\-]*")
_LABEL = re.compile(r"[A-Za-z0-9_](?:[A-Za-z0-9_\-]{0,61}[A-Za-z0-9_])?")
_DIGITS = re.compile(r"[0-9]+")
#: a part of a host that inet_aton reads as a number: hex (0x...), octal (a leading 0),
#: decimal
_NUMBER = re.compile(r"0[xX][0-9A-Fa-f]*|[0-9]+")
#: the bits of the last part of an inet_aton address of 1, 2, 3 or 4 parts
_LAST_BITS = {1: 32, 2: 24, 3: 16, 4: 8}
#: a DNS name is at most 253 characters (without a trailing dot), a label 63
MAX_NAME = 253
MAX_LABEL = 63
#: the hosts a `ProtocolSpec.local_only` endpoint may name
LOCAL_HOSTS = frozenset({"localhost", "127.0.0.1", "::1"})


class EndpointError(ValueError):
    """An endpoint refused. The message names it with any userinfo hidden."""


@dataclass(frozen=True, slots=True)
class Endpoint:
    """A checked endpoint: `host` is ASCII (an IPv6 address without its
    brackets, a name in its IDNA form), `path` is ``""`` or starts with ``/``."""

    scheme: str
    host: str
    port: int
    path: str = ""

    @property
    def netloc(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"

    @property
    def url(self) -> str:
        return f"{self.scheme}://{self.netloc}{self.path}"


def _split_scheme(url: str) -> tuple[str, str, str]:
    """(scheme, ``"scheme:"`` and every slash after it, the rest); ``("", "",
    url)`` when `url` does not start with a scheme and a slash."""
    scheme, sep, _ = url.partition(":")
    if sep and _SCHEME.fullmatch(scheme) and url[len(scheme) + 1:].startswith("/"):
        rest = url[len(scheme) + 1:]
        slashes = len(rest) - len(rest.lstrip("/"))
        return scheme, url[:len(scheme) + 1 + slashes], rest[slashes:]
    return "", "", url


def userinfo(url: str) -> str | None:
    """What stands between ``scheme://`` (or the start, without a scheme) and
    the last ``@``: the user name and password; None without an ``@``."""
    _, _, rest = _split_scheme(url)
    at = rest.rfind("@")
    return None if at < 0 else rest[:at]


def redact_endpoint(url: str) -> str:
    """`url` with its whole userinfo hidden: ``scheme://***@host``. The user
    name goes too: where a raw password ends and the user name begins cannot
    be told (``u:p:w@``, or a password typed where the user goes)."""
    _, head, rest = _split_scheme(url)
    at = rest.rfind("@")
    return url if at < 0 else f"{head}***{rest[at:]}"


def credentials_reason(url: str) -> str | None:
    """Why `url` is refused for holding a user name or password, or None."""
    info = userinfo(url)
    if info is None:
        return None
    what = "a user name and password" if ":" in info else "a user name"
    return f"holds {what}; credentials never go in a URL"


def _port(text: str) -> int:
    """The port; ValueError with the reason."""
    if text == "":
        raise ValueError("an empty port (give one, or leave out the ':')")
    if not _DIGITS.fullmatch(text):
        raise ValueError(f"port {text!r} is not a number")
    if len(text) > 5 or not 1 <= int(text) <= 65535:
        raise ValueError(f"port {text} is out of range 1..65535")
    return int(text)


def _number(part: str) -> int | None:
    """A part as inet_aton reads it (hex, octal, decimal); None where it reads none (a
    bare 0x, an octal part with an 8 or 9)."""
    if part[:2] in ("0x", "0X"):
        return int(part[2:], 16) if len(part) > 2 else None
    if len(part) > 1 and part.startswith("0"):
        return int(part, 8) if set(part) <= set("01234567") else None
    return int(part)


def _numeric_address(parts: list[str]) -> str | None:
    """The IPv4 address inet_aton reads from numeric `parts` (1 to 4), or None."""
    values = [_number(p) for p in parts]
    if not 1 <= len(values) <= 4 or any(v is None for v in values):
        return None
    head = [v for v in values[:-1] if v is not None]
    last = values[-1]
    if last is None or any(v > 0xFF for v in head) or last >= 1 << _LAST_BITS[len(values)]:
        return None
    value = last
    for i, v in enumerate(head):
        value |= v << (24 - 8 * i)
    return str(ipaddress.IPv4Address(value))


def numeric_host_reason(text: str) -> str | None:
    """Why `text` is refused as a host made of numbers only but not an IPv4 address's
    dotted quad; None for the dotted quad and for a name (a part that is no number).

    The C resolver (inet_aton, behind getaddrinfo and so behind every protocol library)
    reads one to four numbers, each decimal, octal (a leading 0) or hex (0x), as an IPv4
    address: ``0x7f000001``, ``127.1`` and ``0177.0.0.1`` are all 127.0.0.1, and
    ``010.0.0.1`` is 8.0.0.1, not 10.0.0.1. A host that looks like a name or a typo must
    not reach an address nobody wrote down, so the one spelling taken is the dotted quad
    (four decimal numbers 0..255 without leading zeros, as `ipaddress` writes it)."""
    parts = (text[:-1] if text.endswith(".") else text).split(".")
    if not all(_NUMBER.fullmatch(p) for p in parts):
        return None
    with contextlib.suppress(ValueError):
        if str(ipaddress.IPv4Address(text)) == text:
            return None
    meant = _numeric_address(parts)
    if meant is None:
        return f"{text} is not an IPv4 address"
    return f"{text} is a numeric spelling of {meant}: write the address as {meant}"


def _host(text: str) -> str:
    """The host in ASCII; ValueError with the reason."""
    if text.startswith("["):
        if not text.endswith("]"):
            raise ValueError("an IPv6 address without its closing ']'")
        inner = text[1:-1].replace("%25", "%")
        try:
            ipaddress.IPv6Address(inner)
        except ValueError:
            raise ValueError(f"{text} is not an IPv6 address") from None
        return inner
    if not text:
        raise ValueError("no host")
    if ":" in text:
        raise ValueError("an IPv6 address goes in brackets: [::1]:502")
    numeric = numeric_host_reason(text)
    if numeric is not None:
        raise ValueError(numeric)
    with contextlib.suppress(ValueError):
        return str(ipaddress.IPv4Address(text))  # the dotted quad
    name = text
    if not name.isascii():
        try:
            name = name.encode("idna").decode("ascii")
        except UnicodeError as exc:
            raise ValueError(f"host name {text!r} has no IDNA form ({exc})") from None
    bare = name[:-1] if name.endswith(".") else name
    if len(bare) > MAX_NAME:
        raise ValueError(f"host name is {len(bare)} characters; at most {MAX_NAME}")
    for label in bare.split("."):
        if len(label) > MAX_LABEL:
            raise ValueError(f"host label {label[:16]!r}... is {len(label)} characters; "
                             f"at most {MAX_LABEL}")
        if label.startswith("-") or label.endswith("-"):
            raise ValueError(f"host label {label!r} starts or ends with '-'")
        if not _LABEL.fullmatch(label):
            raise ValueError(f"host name {text!r} has an empty label or a character other "
                             "than letters, digits, '-' and '_'")
    return name


def parse_endpoint(url: str, spec: ProtocolSpec) -> Endpoint:
    """`url` checked as an endpoint of `spec`'s protocol (see the module
    docstring); `EndpointError` with the reason otherwise."""
    shown = redact_endpoint(url)

    def refuse(reason: str) -> EndpointError:
        return EndpointError(f"not a valid {spec.title} endpoint: {shown!r} ({reason}; expected "
                             f"{spec.endpoint_form})")

    why = credentials_reason(url)
    if why is not None:
        raise refuse(f"it {why}")
    scheme, head, rest = _split_scheme(url)
    if any(c.isspace() or not c.isprintable() for c in url):
        raise refuse("a space or control character")
    if scheme:
        if scheme.lower() not in (spec.scheme, *spec.scheme_aliases):
            raise refuse(f"the scheme is {scheme.lower()!r}")
        if head != scheme + "://":
            raise refuse("'://' must be followed by the host" if len(head) > len(scheme) + 3
                         else "the scheme must be followed by '//'")
    elif not spec.bare_host_port or "://" in url:
        raise refuse("no scheme")
    cut = min((i for i in (rest.find(c) for c in "/?#") if i >= 0), default=len(rest))
    authority, tail = rest[:cut], rest[cut:]
    if "?" in tail or "#" in tail:
        raise refuse("a query or fragment ('?', '#') has no meaning here")
    path = tail
    if path not in ("", "/") and not spec.endpoint_path:
        raise refuse(f"a path ({path!r}) has no meaning here")
    if authority.startswith("["):
        close = authority.find("]")
        host_text, after = authority[:close + 1], authority[close + 1:]
        if close < 0 or (after and not after.startswith(":")):
            raise refuse("a malformed IPv6 address")
        port_text: str | None = after[1:] if after else None
    else:
        host_text, colon, port_text = authority.rpartition(":")
        if not colon:
            host_text, port_text = authority, None
    try:
        host = _host(host_text)
        port = spec.default_port if port_text is None else _port(port_text)
    except ValueError as exc:
        raise refuse(str(exc)) from None
    if spec.local_only and host not in LOCAL_HOSTS:
        raise refuse(f"{spec.title} is on this machine only (local shared memory), "
                     f"not {host!r}")
    return Endpoint(spec.scheme, host, port, path if spec.endpoint_path else "")


def endpoint_of(protocol: str, url: str) -> Endpoint:
    """`parse_endpoint` for the protocol named `protocol`."""
    return parse_endpoint(url, PROTOCOLS[protocol])
