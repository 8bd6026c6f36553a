"""SNMPv3's user-based security (USM) as both ends of hils use it through pysnmp: what can fail and why.

The middleware's transport (:mod:`hils.shell.snmp`) and the emulator's agent (:mod:`emulator.agent.snmp`) both secure
SNMPv3 with pysnmp's USM: HMAC-SHA-96 authentication (RFC 3414 section 7) and AES-128 privacy (RFC 3826).
This module is what they share, so that a refusal reads the same from either end:

- :class:`UsmFailure`: why an exchange failed. An agent tells a manager only by the usmStats counter its
  Report carries (RFC 3414 sections 3.2 and 5); each failure is named by that counter and says what differs
  between the two ends. :meth:`UsmFailure.of` reads pysnmp's error indication (either end's).
- :func:`services_missing`: whether pysnmp's HMAC-SHA-96 and AES-128 work in this Python environment.
  pysnmp imports its ciphers from the ``cryptography`` package and, when that fails, keeps going: every
  authPriv message then fails at run time with "Ciphering services not available" (and an agent answers
  "decryption error"). So both ends check before they start, on known answers: RFC 3414 A.3.2's localized
  key, the HMAC against the standard library's, and NIST SP 800-38A F.3.13's AES-128-CFB vector.
"""

from __future__ import annotations

import functools
import hashlib
import hmac
from enum import Enum
from importlib.metadata import PackageNotFoundError, version

#: The cryptography release pysnmp's AES needs: it imports CFB from ``hazmat.decrepit.ciphers.modes``, new in 47.
CRYPTOGRAPHY_NEEDED = "cryptography>=47"


class UsmFailure(Enum):
    """Why a USM exchange failed; the value is the usmStats counter an agent's Report names (RFC 3414 5)."""

    UNSUPPORTED_SEC_LEVEL = "usmStatsUnsupportedSecLevels"
    NOT_IN_TIME_WINDOW = "usmStatsNotInTimeWindows"
    UNKNOWN_USER_NAME = "usmStatsUnknownUserNames"
    UNKNOWN_ENGINE_ID = "usmStatsUnknownEngineIDs"
    WRONG_DIGEST = "usmStatsWrongDigests"
    DECRYPTION_ERROR = "usmStatsDecryptionErrors"

    @property
    def meaning(self) -> str:
        """What differs between the manager and the agent, in a few words."""
        return _MEANINGS[self]

    def __str__(self) -> str:
        return f"{self.meaning} ({self.value})"

    @classmethod
    def of(cls, indication: object) -> UsmFailure | None:
        """The failure a pysnmp error indication stands for (a manager's from a Report, an agent's from its
        own checks), or None for any other indication."""
        from pysnmp.proto import errind

        by_class = {
            errind.UnsupportedSecurityLevel: cls.UNSUPPORTED_SEC_LEVEL,
            errind.NotInTimeWindow: cls.NOT_IN_TIME_WINDOW,
            errind.UnknownUserName: cls.UNKNOWN_USER_NAME,  # a manager reading the Report
            errind.UnknownSecurityName: cls.UNKNOWN_USER_NAME,  # the agent finding no such user
            errind.UnknownEngineID: cls.UNKNOWN_ENGINE_ID,
            errind.WrongDigest: cls.WRONG_DIGEST,
            errind.AuthenticationFailure: cls.WRONG_DIGEST,  # the agent comparing the digest
            errind.DecryptionError: cls.DECRYPTION_ERROR,
        }
        return by_class.get(type(indication))


_MEANINGS = {
    UsmFailure.UNSUPPORTED_SEC_LEVEL: "security level not allowed for the user (authNoPriv for a user that needs "
                                      "privacy, or the other way round)",
    UsmFailure.NOT_IN_TIME_WINDOW: "engine boots and time outside the agent's 150 s window (a client out of step "
                                   "with an agent that restarted)",
    UsmFailure.UNKNOWN_USER_NAME: "no such user at the agent",
    UsmFailure.UNKNOWN_ENGINE_ID: "unknown engine ID (engine discovery)",
    UsmFailure.WRONG_DIGEST: "wrong digest: the authentication key or protocol differs between manager and agent",
    UsmFailure.DECRYPTION_ERROR: "decryption error: the privacy key or protocol differs between manager and agent",
}


def services_missing(privacy: bool = True) -> str | None:
    """Why pysnmp cannot secure SNMPv3 here, authentication (and with ``privacy`` AES-128) tried on known
    answers; None when it can. The text says what to install."""
    return _auth_missing() or (_privacy_missing() if privacy else None)


@functools.cache
def _auth_missing() -> str | None:
    from pyasn1.type import univ
    from pysnmp.proto.secmod.rfc3414 import localkey
    from pysnmp.proto.secmod.rfc3414.auth.hmacsha import HmacSha

    # RFC 3414 A.3.2: "maplesyrup" localized to engine ID 00..02 with SHA.
    key = localkey.password_to_key_sha(univ.OctetString(b"maplesyrup"), univ.OctetString(bytes(11) + b"\x02"))
    if key.asOctets().hex() != "6695febc9288e36282235fc7151f128497b38f3f":
        return "pysnmp's SHA key localization (RFC 3414 A.2.2) gives a wrong key"
    message = b"\x30\x12" + bytes(12) + b"hils"
    signed = HmacSha().authenticate_outgoing_message(key, message)
    if signed[2:14] != hmac.new(key.asOctets(), message, hashlib.sha1).digest()[:12]:
        return "pysnmp's HMAC-SHA-96 (RFC 3414 7) gives a wrong digest"
    return None


@functools.cache
def _privacy_missing() -> str | None:
    from pyasn1.type import univ
    from pysnmp.proto import error
    from pysnmp.proto.secmod.rfc3414 import service  # noqa: F401  (pysnmp's aes module imports it circularly)
    from pysnmp.proto.secmod.rfc3826.priv.aes import Aes

    # NIST SP 800-38A F.3.13 (CFB128-AES128.Decrypt); the IV is boots, time and salt (RFC 3826 3.1.2.1).
    key = univ.OctetString(bytes.fromhex("2b7e151628aed2a6abf7158809cf4f3c"))
    salt = univ.OctetString(bytes.fromhex("08090a0b0c0d0e0f"))
    try:
        plain = Aes().decrypt_data(key, (0x00010203, 0x04050607, salt),
                                   univ.OctetString(bytes.fromhex("3b3fd92eb72dad20333449f8e83cfb4a")))
    except error.StatusInformation as exc:
        try:
            installed = version("cryptography")
        except PackageNotFoundError:
            installed = "none"
        return (f"SNMPv3 privacy (AES-128) does not work in this Python environment: pysnmp says "
                f"'{exc['errorIndication']}'; it needs the cryptography package ({CRYPTOGRAPHY_NEEDED}, "
                f"installed: {installed}): pip install '{CRYPTOGRAPHY_NEEDED}'")
    if bytes(plain).hex() != "6bc1bee22e409f96e93d7e117393172a":
        return "pysnmp's AES-128-CFB (RFC 3826) decrypts NIST SP 800-38A's vector wrongly"
    return None
