"""The text of a `compd plan` comment, made plain for every dialect.

A comment is not always inert: LinuxCNC runs one that starts with a command
word, ``(MSG,…)`` shows a message, ``(LOGOPEN,file)`` opens and truncates a
file, ``(PROBEOPEN file)`` another, ``(PY,…)`` runs Python, ``(ABORT,…)``
stops the program (its interpreter skips spaces and case first); FANUC ends
the record at ``%`` and a comment at the first ``)``; SINUMERIK's editor
reads ``;*RO*``, ``;*HD*`` and ``;#SM`` markers. So a comment's text is held
to letters, digits, the space and ``. , + - / * = : ' ? & [ ]`` (parentheses
become brackets, ``;`` a comma, anything else ``?``), and one that does not
start with a letter or a digit, or starts with a command word (taken as a
prefix, any case), is led by ``- ``.

The program holds no text the user typed (names, paths): the probe call is
written from its parsed value (`compd.offline.plan.calls`) and the header
names files by what they are, not by their names.
"""

from __future__ import annotations

import re

#: every character outside the set a comment may hold, in any dialect
_NOT_PLAIN = re.compile(r"[^A-Za-z0-9 .,+\-/*=:'?&\[\]]")
_SIGNS = str.maketrans("();", "[],")
#: LinuxCNC's comment commands (rs274ngc's convert_comment) and their kin in
#: other controls (Mach3/4's MSG, PRINT), matched as a prefix of the text
COMMAND_WORDS = ("ABORT", "DEBUG", "LOG", "MSG", "PRINT", "PROBE", "PY", "TASK")
#: what leads a comment that would otherwise start with a command word
LEAD = "- "


def plain(text: str) -> str:
    """`text` in the characters every dialect's comment holds inertly, and
    never starting as a command (see the module)."""
    if not text.strip():
        return "-"
    text = _NOT_PLAIN.sub("?", text.translate(_SIGNS))
    start = text.lstrip()
    if not start[:1].isalnum() or start.upper().startswith(COMMAND_WORDS):
        return LEAD + text
    return text
