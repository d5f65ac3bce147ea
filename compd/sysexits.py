"""The exit codes of every compd command, declared once (sysexits.h).

0 success; 64 usage (a bad option or argument); 65 data error (the input
file's content cannot be used); 66 no input (missing, unreadable or not a
regular file); 69 unavailable (an optional library not installed: pyarrow
for Parquet); 73 cannot create an output; 74 I/O error while writing;
75 temporary failure (try again: a port in use, a lock held); 78 config;
70 internal software error (`compd run` whose cycle raised even as a failed
read: logged, checkpointed, shutdown policy applied; systemd restarts it).
"""

from __future__ import annotations

EX_OK = 0
EX_USAGE = 64
EX_DATAERR = 65
EX_NOINPUT = 66
EX_UNAVAILABLE = 69
EX_SOFTWARE = 70
EX_CANTCREAT = 73
EX_IOERR = 74
EX_TEMPFAIL = 75
EX_CONFIG = 78

#: every code a compd command may end with on bad input (the CLI fuzzer's list);
#: EX_UNAVAILABLE is not among them: it answers a missing library, never an input
EXIT_CODES = frozenset({EX_OK, EX_USAGE, EX_DATAERR, EX_NOINPUT, EX_CANTCREAT, EX_IOERR,
                        EX_TEMPFAIL, EX_CONFIG})
