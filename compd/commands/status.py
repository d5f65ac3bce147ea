"""`compd status [--url URL] [--json]`: what the running daemon's status page says.

Reads ``/status.json`` from the operator page (``[faces.http]``, served
beside ``/metrics``) and prints one line per machine: the state (on /
dry-run / holding / ramping / off) and why, the offset and its limit, the model's
output and how many channels are valid; ``--json``: the document as served.
Exit 0 when every machine compensates (state "on", and a snapshot no older
than three periods: a stalled loop is not on), 1 otherwise; 64 for a
bad URL or argument, 75 when the page cannot be reached (no daemon, no
``[faces.http]``, HTTP error), 65 when what answers is not a compd status
document. Only the standard library is imported (cheap, like `compd health`).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import urllib.error
import urllib.parse
import urllib.request
from typing import Any

from compd.config.urls import redact_urls
from compd.sysexits import EX_DATAERR, EX_TEMPFAIL, EX_USAGE
from drivers.endpoint import numeric_host_reason
from models.nesting import loads_json

HELP = "print what the running daemon's status page says (state, offset, channels)"

DEFAULT_URL = "http://127.0.0.1:9105/status.json"
MAX_TIMEOUT_S = 300.0
#: read at most this much (a status document is a few KB; a fleet's a few hundred)
MAX_BYTES = 16 * 1024 * 1024


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--url", metavar="URL", default=DEFAULT_URL,
                        help="the daemon's page or its status.json (default "
                             f"{DEFAULT_URL}; the daemon's base URL http://HOST:PORT/, or "
                             "the /metrics URL compd health takes, gets status.json)")
    parser.add_argument("--json", action="store_true",
                        help="print the status document as JSON instead of one line per machine")
    parser.add_argument("--timeout-s", metavar="S", type=float, default=5.0,
                        help="how long to wait for the page (default 5)")


class StatusError(Exception):
    """One line for stderr and the exit status."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


def status_url(url: str) -> str:
    """`url` checked (http or https, a host), status.json added to a URL ending in /."""
    try:
        parts = urllib.parse.urlsplit(url)
        parts.port  # noqa: B018 - raises ValueError on a bad port
    except ValueError as exc:
        raise StatusError(f"bad --url: {exc}", EX_USAGE) from None
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise StatusError("bad --url: give http://HOST:PORT/ or http://HOST:PORT/status.json",
                          EX_USAGE)
    numeric = numeric_host_reason(parts.hostname)  # an IPv4 address has one spelling
    if numeric is not None:
        raise StatusError(f"bad --url: {numeric}", EX_USAGE)
    if parts.path in ("", "/", "/metrics"):  # the base URL, or compd health's
        parts = parts._replace(path="/status.json")
    return urllib.parse.urlunsplit(parts)


def fetch(url: str, timeout_s: float) -> dict[str, Any]:
    """The status document at `url`; StatusError when unreachable or not one."""
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as resp:
            body = resp.read(MAX_BYTES + 1)
    except urllib.error.HTTPError as exc:
        hint = " (is [faces.http] enabled?)" if exc.code == 404 else ""
        raise StatusError(f"{url}: HTTP {exc.code}{hint}", EX_TEMPFAIL) from None
    except (urllib.error.URLError, OSError, ValueError) as exc:
        raise StatusError(f"{url}: {getattr(exc, 'reason', exc)}", EX_TEMPFAIL) from None
    if len(body) > MAX_BYTES:
        raise StatusError(f"{url}: answer larger than {MAX_BYTES} bytes", EX_DATAERR)
    try:  # a hostile page: nested without end (RecursionError), integers beyond a float
        doc = loads_json(body.decode("utf-8"), parse=lambda text: json.loads(
            text, parse_int=_number))
    except (ValueError, UnicodeDecodeError):
        raise StatusError(f"{url}: not JSON (not a compd status page)", EX_DATAERR) from None
    machines = doc.get("machines", [doc]) if isinstance(doc, dict) else None
    if not (isinstance(machines, list)
            and all(isinstance(m, dict) and isinstance(m.get("state"), str)
                    for m in machines)):
        raise StatusError(f"{url}: not a compd status document", EX_DATAERR)
    return dict(doc)


def _number(text: str) -> int | float:
    """A JSON integer; one too large for a float (10**400 ends `:.0f` and
    math.isfinite in OverflowError) is inf, as the page never sends it."""
    value = int(text)
    return value if abs(value) < 2**63 else (math.inf if value > 0 else -math.inf)


def _um(value: Any) -> str:
    if isinstance(value, int | float) and math.isfinite(value):
        return f"{value:.2f} um"
    return "-"


def describe(machine: dict[str, Any]) -> str:
    """One machine's line."""
    listed = machine.get("channels")
    channels = [c for c in listed if isinstance(c, dict)] if isinstance(listed, list) else []
    valid = sum(1 for c in channels if c.get("valid") is True)
    limit = machine.get("limit_um")
    limit_text = f" (limit +-{limit:g} um)" if isinstance(limit, int | float) else ""
    late = f"; NO CYCLE FOR {machine['age_s']:.0f} s" if stalled(machine) else ""
    return (f"{machine.get('machine') or '?'}: {machine['state']} - {machine.get('why', '')}; "
            f"offset {_um(machine.get('offset_um'))}{limit_text}, model "
            f"{_um(machine.get('model_um'))}{_model_text(machine)}, "
            f"channels {valid}/{len(channels)} valid{late}")


def _model_text(machine: dict[str, Any]) -> str:
    """How the model started and its reference state in force, as the page gives them."""
    parts: list[str] = []
    start = machine.get("model_start")
    if isinstance(start, str) and start:
        parts.append(f"started {start}")
    ref = machine.get("reference")
    temps = ref.get("temperatures_c") if isinstance(ref, dict) else None
    if isinstance(ref, dict) and isinstance(temps, dict) and temps:
        listed = ", ".join(f"{k} {v:g}" for k, v in temps.items()
                           if isinstance(k, str) and isinstance(v, int | float))
        parts.append(f"reference ({ref.get('source') or '?'}) {listed} C")
    return f" ({'; '.join(parts)})" if parts else ""


def stalled(machine: dict[str, Any]) -> bool:
    """The snapshot is older than three periods (and 2 s): the loop has stalled."""
    age, period = machine.get("age_s"), machine.get("period_s")
    return (isinstance(age, int | float) and isinstance(period, int | float)
            and age > 3.0 * period + 2.0)


def run(args: argparse.Namespace) -> int:
    timeout_s: float = args.timeout_s
    try:
        if not (math.isfinite(timeout_s) and 0 < timeout_s <= MAX_TIMEOUT_S):
            raise StatusError(f"--timeout-s must be a number of seconds in (0, "
                              f"{MAX_TIMEOUT_S:g}]", EX_USAGE)
        doc = fetch(status_url(args.url), timeout_s)
    except StatusError as exc:
        print(f"compd status: {redact_urls(str(exc))}", file=sys.stderr)
        return exc.code
    machines: list[dict[str, Any]] = doc.get("machines", [doc])
    if args.json:
        print(json.dumps(doc, indent=2, sort_keys=True))
    else:
        for machine in machines:
            print(describe(machine))
    sys.stdout.flush()
    return 0 if machines and all(m["state"] == "on" and not stalled(m)
                                 for m in machines) else 1
