"""Credentials never travel in a URL: finding them, and hiding them in text.

A URL like ``opc.tcp://user:secret@host:4840`` carries its password in the
clear: in the config, in every log line that names the endpoint, and (with
security policy None) on the wire. compd refuses such a URL in the config
(`url_credentials` says why) and, as a second line of defence, every place that
prints or logs text passes it through `redact_urls`, which replaces the password
of any URL in the text with ``***`` (``scheme://user:***@host``, as pip and
git print them).
"""

from __future__ import annotations

import re
from urllib.parse import urlsplit

__all__ = ["redact_urls", "url_credentials"]

#: scheme://user:password@ : the password is what `redact_urls` hides
_USERINFO = re.compile(r"(?P<head>\b[A-Za-z][A-Za-z0-9+.\-]*://[^/\s@?#:]*):[^/\s@?#]*@")


def url_credentials(url: str) -> str | None:
    """Why `url` is refused (it holds a user name or password), or None."""
    if "@" not in url:
        return None
    try:
        parts = urlsplit(url)
    except ValueError:
        return None
    if parts.password is not None:
        return "holds a user name and password; credentials never go in a URL"
    if parts.username is not None:
        return "holds a user name; credentials never go in a URL"
    return None


def redact_urls(text: str) -> str:
    """`text` with the password of every URL in it replaced by ``***``."""
    if "@" not in text:
        return text
    return _USERINFO.sub(r"\g<head>:***@", text)
