"""Logging (structlog): JSON lines when stderr is not a terminal (journald, a
container, a file), readable key=value lines on one. Events are names
(``cycle_overrun``, ``controller_reconnected``), not sentences; the details
go in keys. No secret reaches a log line: values of keys that name a secret
(password, secret, token, credential, ...) become ``***``, and every string
registered with `register_secret` (the controller password the daemon
loaded) is replaced by ``***`` wherever it appears in any value, exception
text included. Records of the standard `logging` module (the protocol
libraries log there) go through the same chain; those libraries log at
WARNING and above by default (pymodbus CRITICAL), `[telemetry]
library_log_level` otherwise.

Under systemd (``$JOURNAL_STREAM`` names the device:inode of our stderr) each
line starts with the sd-daemon priority prefix (``<4>`` warning, ``<3>``
error, ...), so that journald files it at its level and ``journalctl -p
warning`` shows compd's warnings.
"""

from __future__ import annotations

import logging
import os
import re
import sys
import threading
from collections.abc import Mapping
from typing import Any, TextIO, cast

import structlog
from structlog.typing import EventDict, Processor, WrappedLogger

from compd.config.urls import redact_urls

__all__ = ["REDACTED", "LogStream", "clear_secrets", "configure_logging", "redact",
           "register_secret"]
REDACTED = "***"
_SECRET_KEY = re.compile(
    r"password|passwd|passphrase|secret|token|credential|api_?key|private_?key", re.IGNORECASE)
#: structlog's bookkeeping for stdlib records: left alone (removed before rendering)
_META_KEYS = frozenset({"_record", "_from_structlog"})
_secrets: set[str] = set()
_secrets_lock = threading.Lock()
_secrets_pattern: re.Pattern[str] | None = None


def register_secret(value: str) -> None:
    """Redact `value` wherever it appears in a log line from now on (empty: ignored)."""
    global _secrets_pattern  # noqa: PLW0603 - one registry per process, by design
    if not value:
        return
    with _secrets_lock:
        _secrets.add(value)
        # longest first, so that a secret containing another is replaced whole
        alternatives = sorted(_secrets, key=len, reverse=True)
        _secrets_pattern = re.compile("|".join(re.escape(s) for s in alternatives))


def clear_secrets() -> None:
    """Forget every registered secret (for tests)."""
    global _secrets_pattern  # noqa: PLW0603
    with _secrets_lock:
        _secrets.clear()
        _secrets_pattern = None


def _scrub(value: Any, pattern: re.Pattern[str] | None) -> Any:
    if isinstance(value, str):
        value = redact_urls(value)  # user:password@ in any URL, registered or not
        return pattern.sub(REDACTED, value) if pattern is not None else value
    if value is None or isinstance(value, bool | int | float):
        return value
    if isinstance(value, Mapping):
        return {k: (REDACTED if isinstance(k, str) and _SECRET_KEY.search(k)
                    else _scrub(v, pattern)) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [_scrub(v, pattern) for v in value]
    text = str(value)  # an object whose text may carry a secret (an exception, a URL)
    scrubbed = redact_urls(text)
    if pattern is not None:
        scrubbed = pattern.sub(REDACTED, scrubbed)
    return scrubbed if scrubbed != text else value


def redact(_logger: WrappedLogger, _name: str, event_dict: EventDict) -> EventDict:
    """structlog processor: hide secret-named keys and registered secret strings."""
    pattern = _secrets_pattern
    for key in list(event_dict):
        if key in _META_KEYS:
            continue
        if _SECRET_KEY.search(key):
            event_dict[key] = REDACTED
        else:
            event_dict[key] = _scrub(event_dict[key], pattern)
    return event_dict


class LogStream:
    """The stream log lines go to, made safe for the daemon: a line that cannot
    be written (a full disk under a log file, a closed pipe) is dropped and
    counted in `dropped_lines`, never raised into the compensation loop.

    Each line reaches the stream whole, in one write and a flush: the text of a
    line is held until its newline (`print` writes a message and its end
    apart). Processes that share one stderr (`compd run DIR --workers N`: the
    parent and its workers) then never splice one line into another."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.dropped_lines = 0
        self._pending = ""

    def write(self, text: str) -> int:
        taken = len(text)
        text = self._pending + text
        head, newline, self._pending = text.rpartition("\n")
        if newline:
            try:
                self.stream.write(head + newline)
                self.stream.flush()
            except (OSError, ValueError):  # ENOSPC, EIO, EPIPE; ValueError: closed
                self.dropped_lines += 1
        return taken

    def flush(self) -> None:
        if self._pending:  # a line without its newline yet: written as it is
            text, self._pending = self._pending, ""
            try:
                self.stream.write(text)
            except (OSError, ValueError):
                self.dropped_lines += 1
        try:
            self.stream.flush()
        except (OSError, ValueError):
            self.dropped_lines += 1

    def isatty(self) -> bool:
        try:
            return self.stream.isatty()
        except (OSError, ValueError):
            return False


#: The least level the protocol libraries log at (whatever the daemon's level),
#: unless `[telemetry] library_log_level` says otherwise.
LIBRARY_LOG_FLOOR = {"asyncua": logging.WARNING, "snap7": logging.WARNING,
                     "pymodbus": logging.CRITICAL}

#: sd-daemon(3) priority prefixes by structlog level name
SD_PRIORITY = {"critical": 2, "exception": 3, "error": 3, "warning": 4, "warn": 4,
               "notice": 5, "info": 6, "debug": 7}


def is_journal_stream(stream: TextIO, env: Mapping[str, str] | None = None) -> bool:
    """True when `stream` is the journal's stream socket: $JOURNAL_STREAM
    ("device:inode", set by systemd) matches the stream's file."""
    value = (os.environ if env is None else env).get("JOURNAL_STREAM", "")
    dev, _, ino = value.partition(":")
    if not (dev.isdigit() and ino.isdigit()):
        return False
    try:
        st = os.fstat(stream.fileno())
    except (OSError, ValueError, AttributeError):  # closed, or not a file (io.StringIO)
        return False
    return (st.st_dev, st.st_ino) == (int(dev), int(ino))


def _with_priority(renderer: Processor) -> Processor:
    """`renderer`, each line prefixed with its sd-daemon ``<N>`` priority."""
    def render(logger: WrappedLogger, name: str, event_dict: EventDict) -> Any:
        level = str(event_dict.get("level", name)).lower()
        line = renderer(logger, name, event_dict)
        prefix = f"<{SD_PRIORITY.get(level, 6)}>"
        return prefix.encode() + line if isinstance(line, bytes) else prefix + str(line)
    return render


def library_floors(level: str = "default") -> dict[str, int]:
    """The least level of each protocol library's logger (`library_log_level`)."""
    if level == "default":
        return dict(LIBRARY_LOG_FLOOR)
    levelno = logging.getLevelNamesMapping()[level.upper()]
    return dict.fromkeys(LIBRARY_LOG_FLOOR, levelno)


#: the least level `configure_logging` lets through (NOTSET until it is called, as
#: structlog's own default lets everything through); one item, set in place
_least_level = [logging.NOTSET]


def logs_at(levelno: int) -> bool:
    """Whether a line at `levelno` is written (the level `configure_logging` set):
    asked before building a line that is made every cycle and read only at debug."""
    return levelno >= _least_level[0]


def configure_logging(json: bool | None = None, level: str = "info", *,
                      stream: TextIO | None = None, library_level: str = "default",
                      journal: bool | None = None) -> None:
    """Set up structlog (and the stdlib root logger) for the daemon.

    `json`: True JSON lines, False key=value, None decide by ``stream.isatty()``.
    `level`: debug, info, warning, error or critical. `stream`: where lines go,
    sys.stderr (looked up at call time) by default. `library_level`: see
    `library_floors`. `journal`: prefix the sd-daemon priority; None: when
    `is_journal_stream(stream)`.
    """
    target = stream if stream is not None else sys.stderr
    out = LogStream(target)
    if journal is None:
        journal = is_journal_stream(target)
    levelno = logging.getLevelNamesMapping().get(level.upper())
    if levelno is None:
        raise ValueError(f"unknown log level {level!r}")
    as_json = (not out.isatty()) if json is None else json
    shared: list[Processor] = [
        structlog.contextvars.merge_contextvars,
        structlog.processors.add_log_level,
        structlog.processors.TimeStamper(fmt="iso", utc=True),
        structlog.processors.StackInfoRenderer(),
        structlog.processors.format_exc_info,  # exception text, so that it is redacted too
        redact,
    ]
    renderer: Processor
    if as_json:
        renderer = structlog.processors.JSONRenderer(sort_keys=False)
    else:
        renderer = structlog.dev.ConsoleRenderer(colors=False)
    if journal:
        renderer = _with_priority(renderer)
    _least_level[0] = levelno
    structlog.configure(
        processors=[*shared, renderer],
        wrapper_class=structlog.make_filtering_bound_logger(levelno),
        logger_factory=structlog.PrintLoggerFactory(file=cast(TextIO, out)),
        cache_logger_on_first_use=False,
    )
    # the protocol libraries log through `logging`: same format, same redaction
    handler = logging.StreamHandler(out)
    handler.setFormatter(structlog.stdlib.ProcessorFormatter(
        foreign_pre_chain=[structlog.stdlib.add_logger_name, *shared],
        processors=[structlog.stdlib.ProcessorFormatter.remove_processors_meta, renderer],
    ))
    handler.set_name("compd")
    root = logging.getLogger()
    for old in [h for h in root.handlers if h.get_name() == "compd"]:
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(levelno)
    # the libraries report what our drivers report again (a failed request is one
    # read_failed/write_failed line of ours): their INFO is noise (asyncua dumps 6 KB of
    # endpoints on every connect) and pymodbus logs each failed frame as an ERROR hex dump
    for name, floor in library_floors(library_level).items():
        logging.getLogger(name).setLevel(max(levelno, floor) if library_level == "default"
                                         else floor)
