"""`compd health [--url URL] [--state-dir DIR] [--max-age-s S]`: is the daemon healthy?

For container health checks and monitoring scripts. Exit 0 when healthy, 1
otherwise, with one line saying why; 64 for a bad argument. Healthy means
the offset compd wants is in force NOW (the last cycle's cause,
`compd.core.health.Cause`, is ``in_force``, an operator's ``operator_hold`` or
``waiting_for_permission`` (the controller holds the change back by design),
or ``degraded`` (a fallback model stands in for a failed sensor: healthy, the
machine is compensated from valid inputs, with a warning on the line);
any other cause, a model worse than none, invalid inputs, the controller off,
a failed write, a foreign offset, the limit ..., is unhealthy and named), and
a COMPLETE cycle (inputs read and valid, model stepped, offset write
confirmed by the controller) no longer than ``--max-age-s`` ago, shown by
either

* the metrics endpoint (``--url http://127.0.0.1:PORT/metrics``): at least one
  ``compd_cycles_complete_total``, ``compd_last_complete_cycle_age_seconds``
  (measured by the daemon on the monotonic clock) within the age,
  ``compd_offset_not_in_force`` 0 (``compd_output_cause`` names the cause
  otherwise) and a fault state below 3 (alarm/stopped); or
* the state directory: the checkpoint's record of the last complete cycle,
  read by the daemon's own reader (`compd.runtime.checkpoint.load_checkpoint`:
  a torn, edited or corrupted checkpoint, one of another owner than the state
  directory's, or a link, proves nothing, as the daemon would not restore it)
  (`compd.runtime.liveness`: judged on the monotonic clock within one boot,
  on the wall clock otherwise; a stamp in the future is no evidence), and
  the cause and fault state of the cycle before it was written
  (``last_cause`` healthy, ``last_state`` below alarm): the daemon writes a
  checkpoint at once when the offset it wants goes out of force or back
  in, and when it enters or leaves the alarm, so both sources turn red
  together.

A complete cycle is one whose offset is the one compd wants, in force
(`compd.core.cycle.offset_in_force`): a held output (a foreign offset
beyond the limit), a write fault or stopped writes never count.

A daemon that cycles without a controller, or whose writes fail, is not
healthy, however busy it is: cycles that ran prove nothing, and neither do
the recorder's files. With both sources given, either one suffices (the report
names both). With neither, the state directory is ``$STATE_DIRECTORY`` (set
by systemd) or ``/var/lib/compd``. Only the standard library (and compd's
stdlib-only checkpoint reader) is imported: a health check runs every few
seconds and must stay cheap.
"""

from __future__ import annotations

import argparse
import http.client
import math
import os
import stat
import sys
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

from compd.config.urls import redact_urls
from compd.core.faults import GAUGE_ALARM, FaultState
from compd.core.health import Cause
from compd.runtime.checkpoint import CHECKPOINT_NAME, CheckpointError, load_checkpoint
from compd.runtime.liveness import last_complete_age_s
from compd.sysexits import EX_USAGE
from drivers.endpoint import numeric_host_reason

HELP = "exit 0 when the running daemon is healthy (metrics endpoint or fresh state), else 1"

DEFAULT_STATE_DIR = Path("/var/lib/compd")
#: a health check waits at most this long for the endpoint, and an age beyond a week is a typo
MAX_TIMEOUT_S = 300.0
MAX_AGE_LIMIT_S = 7 * 86400.0
FAULT_STOPPED = float(GAUGE_ALARM)
_STATES = frozenset(str(s) for s in FaultState)
_CAUSES = frozenset(str(c) for c in Cause)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--url", metavar="URL",
                        help="the daemon's metrics endpoint, e.g. http://127.0.0.1:9105/metrics, "
                             "or its base URL (http://127.0.0.1:9105/, as compd status "
                             "takes): /metrics is added")
    parser.add_argument("--state-dir", metavar="DIR", type=Path,
                        help="the daemon's state directory ([state] dir); default "
                             "$STATE_DIRECTORY or /var/lib/compd when --url is not given")
    parser.add_argument("--max-age-s", metavar="S", type=float, default=180.0,
                        help="the newest evidence of a cycle may be this old (default 180; "
                             "above checkpoint_every × period_s / time_scale)")
    parser.add_argument("--timeout-s", metavar="S", type=float, default=5.0,
                        help="how long to wait for the metrics endpoint (default 5)")


# -- metrics endpoint ------------------------------------------------------------------


def parse_metrics(text: str) -> dict[str, float]:
    """Prometheus text exposition -> {sample name: value}, summed over labels."""
    out: dict[str, float] = {}
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        if "{" in line:
            name, _, rest = line.partition("{")
            _, _, rest = rest.rpartition("}")
        else:
            name, _, rest = line.partition(" ")
        fields = rest.split()
        if not fields:
            continue
        try:
            value = float(fields[0])
        except ValueError:
            continue
        out[name] = out.get(name, 0.0) + value
    return out


def _degraded(text: str) -> str | None:
    """The input whose fallback model is in force (``compd_fallback_in_force`` 1), or None."""
    for line in text.splitlines():
        if line.startswith("compd_fallback_in_force{") and line.rstrip().endswith(" 1.0"):
            labels = line[len("compd_fallback_in_force{"):].rpartition("}")[0]
            key, _, value = labels.partition("=")
            if key.strip() == "lost":
                return value.strip().strip('"')[:64]
    return None


def causes_named(text: str) -> list[str]:
    """The causes ``compd_output_cause{cause="..."}`` sets to 1 that are not healthy
    (several for a fleet's endpoint), sorted; unknown names are kept as sent."""
    out: set[str] = set()
    for raw in text.splitlines():
        line = raw.strip()
        if not line.startswith("compd_output_cause{"):
            continue
        labels, _, rest = line[len("compd_output_cause{"):].rpartition("}")
        fields = rest.split()
        if not fields or fields[0] not in ("1", "1.0"):
            continue
        for item in labels.split(","):
            key, _, value = item.partition("=")
            cause = value.strip().strip('"')
            if key.strip() == "cause" and cause and not (
                    cause in _CAUSES and Cause(cause).healthy):
                out.add(cause[:64])
    return sorted(out)


def check_metrics(url: str, max_age_s: float, timeout_s: float,
                  now_wall_s: float) -> tuple[bool, str]:
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as resp:
            body = resp.read(8 * 1024 * 1024).decode("utf-8", "replace")
    except urllib.error.HTTPError as exc:
        return False, f"metrics {url}: HTTP {exc.code}"
    except http.client.HTTPException as exc:  # not HTTP at all, a reply cut short
        return False, f"metrics {url}: {type(exc).__name__} {exc}".rstrip()
    except (urllib.error.URLError, OSError, ValueError) as exc:
        reason = getattr(exc, "reason", exc)
        return False, f"metrics {url}: {reason}"
    metrics = parse_metrics(body)
    complete = metrics.get("compd_cycles_complete_total")
    if complete is None:
        return False, (f"metrics {url}: no compd_cycles_complete_total "
                       "(not a compd endpoint, or an older compd)")
    if complete < 1:
        return False, f"metrics {url}: no complete cycle yet"
    fault = metrics.get("compd_fault_state")
    if fault is not None and fault >= FAULT_STOPPED:
        return False, f"metrics {url}: fault state {fault:g} (alarm/stopped)"
    if metrics.get("compd_offset_not_in_force", 0.0) > 0:
        why = ", ".join(causes_named(body)) or "cause not named"
        return False, f"metrics {url}: the offset compd wants is not in force ({why})"
    age_s = metrics.get("compd_last_complete_cycle_age_seconds")
    if age_s is None:
        last = metrics.get("compd_last_complete_cycle_timestamp_seconds")
        if last is None:
            return False, f"metrics {url}: no age of the last complete cycle"
        age_s = now_wall_s - last
    if not 0.0 <= age_s <= max_age_s:
        return False, (f"metrics {url}: last complete cycle {age_s:.0f} s ago "
                       f"(max {max_age_s:g} s)")
    degraded = _degraded(body)
    return True, (f"metrics: {complete:.0f} complete cycles, last {age_s:.0f} s ago"
                  + (f"; warning: degraded, fallback model without {degraded} in force"
                     if degraded else ""))


# -- state directory ---------------------------------------------------------------------


def check_state_dir(state_dir: Path, max_age_s: float) -> tuple[bool, str]:
    try:
        st = state_dir.stat()
    except OSError:
        st = None
    if st is None or not stat.S_ISDIR(st.st_mode):
        return False, f"state dir {state_dir}: not a directory"
    try:  # the daemon's reader; the file is the state directory owner's, whoever asks
        state = load_checkpoint(state_dir / CHECKPOINT_NAME, owner=st.st_uid)
    except CheckpointError as exc:
        return False, f"state dir {state_dir}: checkpoint unreadable ({exc.reason})"
    if state is None:
        return False, f"state dir {state_dir}: no checkpoint yet"
    last = state.get("last_state")  # absent in an older compd's checkpoint
    if last in _STATES and FaultState(last).gauge >= FAULT_STOPPED:
        return False, f"state dir {state_dir}: fault state {last} (alarm/stopped)"
    cause = state.get("last_cause")  # absent in an older compd's checkpoint
    if isinstance(cause, str) and not (cause in _CAUSES and Cause(cause).healthy):
        return False, (f"state dir {state_dir}: the offset compd wants is not in force "
                       f"({cause[:64]})")
    age_s, how = last_complete_age_s(state)
    if age_s is None:
        return False, f"state dir {state_dir}: {how}"
    if not age_s <= max_age_s:
        return False, (f"state dir {state_dir}: last complete cycle {age_s:.0f} s ago "
                       f"(max {max_age_s:g} s)")
    warn = ("; warning: degraded, a fallback model is in force"
            if cause == Cause.DEGRADED.value else "")
    return True, f"state dir: last complete cycle {age_s:.0f} s ago ({how}){warn}"


def url_problem(url: str) -> str | None:
    """Why `url` cannot be a metrics endpoint (None when it can): an http(s) URL
    with a host and, if any, a port in 1..65535."""
    try:
        parts = urllib.parse.urlsplit(url)
        port = parts.port  # ValueError: not a number, or out of range
    except ValueError as exc:
        return str(exc)
    if parts.scheme not in ("http", "https"):
        return f"scheme {parts.scheme!r} is not http or https"
    if not parts.hostname:
        return "no host"
    if (numeric := numeric_host_reason(parts.hostname)) is not None:
        return numeric  # the endpoints' rule: an IPv4 address has one spelling
    if port == 0:
        return "port 0"
    if any(c.isspace() or ord(c) < 32 for c in url):
        return "a space or control character in it"
    return None


#: the daemon's other paths on the same port: the metrics are asked for instead
_PAGE_PATHS = frozenset({"", "/", "/status.json", "/index.html"})


def metrics_url(url: str) -> str:
    """`url` as the metrics endpoint: the daemon's base URL (the one `compd status
    --url` takes) or its page's paths become ``/metrics``; any other path is kept."""
    parts = urllib.parse.urlsplit(url)
    if parts.path in _PAGE_PATHS:
        parts = parts._replace(path="/metrics")
    return urllib.parse.urlunsplit(parts)


def _usage(message: str) -> int:
    print(f"compd health: {message}", file=sys.stderr)
    return EX_USAGE


def run(args: argparse.Namespace) -> int:
    max_age_s: float = args.max_age_s
    if not (math.isfinite(max_age_s) and 0 < max_age_s <= MAX_AGE_LIMIT_S):
        return _usage(f"--max-age-s must be a number of seconds in (0, {MAX_AGE_LIMIT_S:g}]")
    timeout_s: float = args.timeout_s
    if not (math.isfinite(timeout_s) and 0 < timeout_s <= MAX_TIMEOUT_S):
        return _usage(f"--timeout-s must be a number of seconds in (0, {MAX_TIMEOUT_S:g}]")
    if args.url is not None and (why := url_problem(args.url)) is not None:
        return _usage(f"--url {redact_urls(args.url)!r}: {why}")
    state_dir: Path | None = args.state_dir
    if state_dir is None and args.url is None:
        state_dir = Path(os.environ.get("STATE_DIRECTORY", "").split(":")[0]
                         or DEFAULT_STATE_DIR)
    now_wall_s = time.time()
    results: list[tuple[bool, str]] = []
    if args.url is not None:
        results.append(check_metrics(metrics_url(args.url), max_age_s, timeout_s, now_wall_s))
    if state_dir is not None:
        results.append(check_state_dir(state_dir, max_age_s))
    healthy = any(ok for ok, _ in results)
    text = "; ".join(msg for _, msg in results)
    print(("healthy: " if healthy else "unhealthy: ") + redact_urls(text))
    sys.stdout.flush()
    return 0 if healthy else 1
