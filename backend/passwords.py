"""Password hashing with scrypt (stdlib): a slow, memory-hard hash against guessing."""

import base64
import hashlib
import hmac
import secrets

# n=2**14, r=8, p=1: ~16 MiB and ~50 ms per hash, the interactive-login setting of the
# scrypt paper; kept in every hash so that it can be raised later without breaking old ones.
SCRYPT_N = 2**14
SCRYPT_R = 8
SCRYPT_P = 1
SALT_BYTES = 16
KEY_BYTES = 32
MIN_PASSWORD_LENGTH = 8
MAX_PASSWORD_LENGTH = 256
# The most common passwords of at least 8 characters (from the published breach lists):
# the first an attacker tries, whatever the rules say.
COMMON_PASSWORDS = frozenset(
    [
        "12345678",
        "123456789",
        "1234567890",
        "password",
        "password1",
        "password123",
        "passw0rd",
        "qwertyuiop",
        "qwerty123",
        "qwertyui",
        "11111111",
        "00000000",
        "iloveyou",
        "1q2w3e4r",
        "1q2w3e4r5t",
        "abc12345",
        "abcd1234",
        "sunshine",
        "princess",
        "football",
        "baseball",
        "welcome1",
        "welcome123",
        "admin123",
        "administrator",
        "letmein1",
        "trustno1",
        "superman",
        "87654321",
        "12341234",
        "asdfghjk",
        "asdfasdf",
        "zaq12wsx",
        "1qaz2wsx",
        "q1w2e3r4",
        "computer",
        "internet",
        "starwars",
        "whatever",
        "dragon12",
        "monkey12",
        "changeme",
        "changeme1",
        "slidewatch",
        "landslide",
    ]
)


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii")


def _scrypt(password: str, salt: bytes, n: int, r: int, p: int) -> bytes:
    return hashlib.scrypt(
        password.encode("utf-8"), salt=salt, n=n, r=r, p=p, dklen=KEY_BYTES, maxmem=64 * 1024**2
    )


def hash_password(password: str) -> str:
    """`scrypt$n$r$p$salt$key`, salt and key in base64."""
    salt = secrets.token_bytes(SALT_BYTES)
    key = _scrypt(password, salt, SCRYPT_N, SCRYPT_R, SCRYPT_P)
    return f"scrypt${SCRYPT_N}${SCRYPT_R}${SCRYPT_P}${_b64(salt)}${_b64(key)}"


def verify_password(password: str, stored: str) -> bool:
    try:
        scheme, n, r, p, salt, key = stored.split("$")
        if scheme != "scrypt":
            return False
        expected = base64.b64decode(key)
        actual = _scrypt(password, base64.b64decode(salt), int(n), int(r), int(p))
    except (ValueError, TypeError):
        return False
    return hmac.compare_digest(actual, expected)


def password_problem(password: str, username: str = "") -> str | None:
    """Why a new password cannot be used, in plain words; None if it can.

    Length and a list of the most guessed passwords, as NIST SP 800-63B advises, rather
    than rules of character classes (which make passwords harder to remember, not to guess).
    """
    if len(password) < MIN_PASSWORD_LENGTH:
        return f"the password must have at least {MIN_PASSWORD_LENGTH} characters"
    if len(password) > MAX_PASSWORD_LENGTH:
        return f"the password may have at most {MAX_PASSWORD_LENGTH} characters"
    if password.strip() == "":
        return "the password cannot be only spaces"
    if len(set(password)) == 1:
        return "the password cannot be one character repeated"
    if username and password.casefold() == username.casefold():
        return "the password cannot be the user name"
    if password.casefold() in COMMON_PASSWORDS:
        return "the password is one of the most common passwords; choose another"
    return None
