"""Credentials never travel in a URL: finding them, and hiding them in text.

A URL like ``opc.tcp://user:secret@host:4840`` carries its password in the
clear: in the config, in every log line that names the endpoint, and (with
security policy None) on the wire. compd refuses such a URL in the config
(`url_credentials` says why; the endpoint's other checks are
`drivers.endpoint`'s, shared with the drivers and ``compd sim --drive``) and,
as a second line of defence, every place that prints or logs text passes it
through `redact_urls`, which replaces the userinfo of any URL in the text
with ``***`` (``scheme://***@host``: the user name goes too, as where a raw
password ends and the user name begins cannot be told).

Where a userinfo ends is read as RFC 3986 reads it *and* as a user who typed
a password raw would: the **last** ``@`` before the host ends it, even when
the password holds ``/``, ``?``, ``#``, ``:``, ``%`` or ``@`` (which a URL
parser would take for the start of the path, query or fragment and so miss
the userinfo), and a typo such as ``opc.tcp:///user:secret@host`` is still
one.
"""

from __future__ import annotations

import re

from drivers.endpoint import credentials_reason, redact_endpoint

__all__ = ["redact_urls", "url_credentials"]

#: ``scheme://`` and the run of characters up to the next white space: a URL in
#: free text (whose password may hold any character but white space)
_URL = re.compile(r"\b[A-Za-z][A-Za-z0-9+.\-]*://\S*")


def url_credentials(url: str) -> str | None:
    """Why `url` is refused (it holds a user name or password), or None.

    Any ``@`` marks a userinfo (the last one ends it): a password with
    ``/``, ``?`` or ``#`` in it hides from `urllib.parse.urlsplit`."""
    return credentials_reason(url)


def redact_urls(text: str) -> str:
    """`text` with the userinfo of every URL in it hidden: ``scheme://***@host``."""
    if "@" not in text:
        return text
    return _URL.sub(lambda m: redact_endpoint(m.group(0)), text)
