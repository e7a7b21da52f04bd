"""E-mail addresses of alert recipients, checked strictly when they are saved.

A recipient ends up in a message header: one carrying a line break (`\\r\\nBcc: …`) or a
NUL would add headers of its sender's choosing, and one the e-mail library cannot parse
makes every delivery to the site fail. Only a plain `local@domain` is taken: the local
part's dot-atom characters of RFC 5322, a domain of letters, digits and hyphens with a
dot (international names in their ASCII form, xn--…).
"""

from __future__ import annotations

import re

MAX_LENGTH = 254  # RFC 5321: the longest path an SMTP server must accept
_LOCAL = re.compile(r"[A-Za-z0-9!#$%&'*+/=?^_`{|}~-]+(\.[A-Za-z0-9!#$%&'*+/=?^_`{|}~-]+)*")
_LABEL = re.compile(r"[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?")


def email_problem(value: str) -> str | None:
    """Why `value` is not a plain e-mail address, in plain words; None if it is one."""
    if any(ord(c) < 32 or ord(c) == 127 for c in value):
        return f"{value!r} is not an e-mail address: it holds a line break or control character"
    if len(value) > MAX_LENGTH:
        return f"{value[:40]!r}… is not an e-mail address: longer than {MAX_LENGTH} characters"
    local, at, domain = value.rpartition("@")
    if not at or not _LOCAL.fullmatch(local) or len(local) > 64:
        return f"{value!r} is not an e-mail address such as name@town.example"
    labels = domain.split(".")
    if len(labels) < 2 or not all(_LABEL.fullmatch(label) for label in labels):
        return f"{value!r} is not an e-mail address: {domain!r} is not a domain name"
    if labels[-1].isdigit():
        return f"{value!r} is not an e-mail address: {domain!r} is not a domain name"
    return None
