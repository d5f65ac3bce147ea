"""HTTP/1.1 on the wire for `compd.faces.http_server`, without sockets or threads.

`parse_request(buf, limit)` takes one request (head and small body) off the
front of a connection's buffer, or says that more bytes are needed; a head
that cannot be served raises `BadRequest` (its status code and the reason it
is counted under). `environ` builds the WSGI environ of a request; `run_app`
calls a WSGI application and returns the whole answer (status line, headers,
body; no body for HEAD); `error_answer` is the short answer of an error,
which closes the connection.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any
from urllib.parse import unquote

__all__ = ["BadRequest", "Request", "WSGIApp", "environ", "error_answer", "parse_request",
           "run_app"]

#: a WSGI application (environ, start_response) -> body
WSGIApp = Callable[[dict[str, Any], Callable[..., Any]], Iterable[bytes]]

_REASON_PHRASE = {400: "Bad Request", 413: "Content Too Large", 414: "URI Too Long",
                  431: "Request Header Fields Too Large", 500: "Internal Server Error",
                  501: "Not Implemented", 503: "Service Unavailable"}


class BadRequest(Exception):
    """A head that cannot be served: answer `code`, count under `reason`, close."""

    def __init__(self, code: int, reason: str, detail: str) -> None:
        super().__init__(detail)
        self.code, self.reason = code, reason


@dataclass(frozen=True)
class Request:
    method: str
    target: str
    version: str
    #: lower-case names; a repeated header's values joined with ", "
    headers: dict[str, str]
    body: bytes
    keep_alive: bool


def parse_request(buf: bytearray, limit: int) -> Request | None:
    """The request at the front of `buf` (removed from it), None while incomplete.

    `limit`: the most bytes of a head, and of a body (Content-Length). A request
    line longer than that is 414, a longer head 431, a longer body 413;
    Transfer-Encoding 501; anything malformed 400."""
    end = buf.find(b"\r\n\r\n")
    sep = 4
    if end < 0:
        end, sep = buf.find(b"\n\n"), 2
    if end < 0 and len(buf) <= limit:
        return None
    if end < 0 or end > limit:
        first = buf.find(b"\n")
        if first < 0 or first > limit:
            raise BadRequest(414, "head_too_large", f"request line longer than {limit} bytes")
        raise BadRequest(431, "head_too_large", f"request head larger than {limit} bytes")
    lines = bytes(buf[:end]).decode("latin-1").replace("\r\n", "\n").split("\n")
    parts = lines[0].split(" ")
    if len(parts) != 3 or not parts[0].isalpha() or not parts[1]:
        raise BadRequest(400, "bad_request", "malformed request line")
    method, target, version = parts
    if version not in ("HTTP/1.0", "HTTP/1.1"):
        raise BadRequest(400, "bad_request", "unsupported HTTP version")
    headers: dict[str, str] = {}
    for line in lines[1:]:
        name, colon, value = line.partition(":")
        if not colon or not name or name != name.strip() or " " in name:
            raise BadRequest(400, "bad_request", "malformed header line")
        key = name.lower()
        value = value.strip(" \t")
        headers[key] = f"{headers[key]}, {value}" if key in headers else value
    if "transfer-encoding" in headers:
        raise BadRequest(501, "not_implemented", "Transfer-Encoding not supported")
    length_text = headers.get("content-length", "0")
    if not length_text.isdigit():
        raise BadRequest(400, "bad_request", "bad Content-Length")
    length = int(length_text)
    if length > limit:
        raise BadRequest(413, "body_too_large", f"request body larger than {limit} bytes")
    start = end + sep
    if len(buf) < start + length:
        return None  # the body is still coming (within the head's deadline)
    body = bytes(buf[start:start + length])
    del buf[:start + length]
    connection = headers.get("connection", "").lower()
    keep_alive = ("close" not in connection if version == "HTTP/1.1"
                  else "keep-alive" in connection)
    return Request(method, target, version, headers, body, keep_alive)


class _Sink(io.RawIOBase):
    """wsgi.errors: what the application writes there is dropped (never stderr)."""

    def writable(self) -> bool:
        return True

    def write(self, data: Any) -> int:
        return len(data)


def environ(request: Request, server_name: str, server_port: int,
            remote_addr: str) -> dict[str, Any]:
    """The WSGI environ (PEP 3333) of `request`."""
    target = request.target
    if "://" in target:  # absolute-form: the path part
        target = "/" + target.split("://", 1)[1].partition("/")[2]
    path, _, query = target.partition("?")
    env: dict[str, Any] = {
        "REQUEST_METHOD": request.method, "SCRIPT_NAME": "",
        "PATH_INFO": unquote(path, "latin-1"), "QUERY_STRING": query,
        "SERVER_NAME": server_name, "SERVER_PORT": str(server_port),
        "SERVER_PROTOCOL": request.version, "REMOTE_ADDR": remote_addr,
        "CONTENT_LENGTH": str(len(request.body)) if request.body else "",
        "CONTENT_TYPE": request.headers.get("content-type", ""),
        "wsgi.version": (1, 0), "wsgi.url_scheme": "http",
        "wsgi.input": io.BytesIO(request.body), "wsgi.errors": _Sink(),
        "wsgi.multithread": True, "wsgi.multiprocess": False, "wsgi.run_once": False,
    }
    for key, value in request.headers.items():
        if key not in ("content-type", "content-length"):
            env["HTTP_" + key.upper().replace("-", "_")] = value
    return env


def run_app(app: WSGIApp, env: dict[str, Any], *, head: bool, keep_alive: bool) -> bytes:
    """`app`'s whole answer to `env`: status line, headers (with Content-Length and
    Connection), and the body unless `head`. What the application raises, raises."""
    started: list[Any] = []
    chunks: list[bytes] = []

    def start_response(status: str, headers: list[tuple[str, str]],
                       exc_info: Any = None) -> Callable[[bytes], None]:
        if exc_info is not None and started:
            raise exc_info[1].with_traceback(exc_info[2])
        started[:] = [status, list(headers)]
        return chunks.append

    result = app(env, start_response)
    try:
        for chunk in result:
            chunks.append(bytes(chunk))
    finally:
        close = getattr(result, "close", None)
        if close is not None:
            close()
    if not started:
        raise RuntimeError("the application did not call start_response")
    status, headers = started
    body = b"".join(chunks)
    lines = [f"HTTP/1.1 {status}"]
    has_length = False
    for name, value in headers:
        if name.lower() in ("connection", "keep-alive", "transfer-encoding"):
            continue  # hop-by-hop: ours to say
        has_length = has_length or name.lower() == "content-length"
        lines.append(f"{name}: {value}")
    if not has_length:
        lines.append(f"Content-Length: {len(body)}")
    lines.append("Connection: " + ("keep-alive" if keep_alive else "close"))
    answer = ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")
    return answer if head else answer + body


def error_answer(code: int, text: str) -> bytes:
    """A short plain-text answer that closes the connection."""
    body = f"{text}\n".encode("latin-1", "replace")
    return (f"HTTP/1.1 {code} {_REASON_PHRASE.get(code, 'Error')}\r\n"
            "Content-Type: text/plain; charset=utf-8\r\n"
            f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n").encode() + body
