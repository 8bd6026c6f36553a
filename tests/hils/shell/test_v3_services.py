"""The SNMPv3 services the README advertises (USM with HMAC-SHA-96 authentication, AES-128 privacy) work in the
environment the project's own files install: every pysnmp module they need imports, and computes what an
independent reference computes. `make test` builds that environment afresh each time, so a package installed by
hand cannot stand in for a missing dependency; without `cryptography` pysnmp's AES still imports and fails only
at run time, which is why the ciphers are run here and not just imported.

Without cryptography (hidden from a subprocess), both ends refuse to start in one line that says what to install,
instead of failing later as "no answer" or "Decryption error".
"""

from __future__ import annotations

import hashlib
import hmac
import importlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

from hils.protocol.usm import CRYPTOGRAPHY_NEEDED, services_missing

# What pysnmp loads for the modes a target URL and `hils emulator serve --v3-user` offer (and the message
# processing and USM they run in).
MODULES = ["pysnmp.proto.mpmod.rfc3412", "pysnmp.proto.secmod.rfc3414.service",
           "pysnmp.proto.secmod.rfc3414.localkey", "pysnmp.proto.secmod.rfc3414.auth.hmacsha",
           "pysnmp.proto.secmod.rfc3826.priv.aes", "cryptography.hazmat.primitives.ciphers",
           "cryptography.hazmat.decrepit.ciphers.modes"]


@pytest.mark.parametrize("module", MODULES)
def test_every_module_of_the_advertised_v3_modes_imports(module: str) -> None:
    importlib.import_module("pysnmp.proto.secmod.rfc3414")  # pysnmp's aes module needs it first (circular)
    importlib.import_module(module)


def test_hmac_sha_96_and_key_localization_compute_the_references() -> None:
    from pyasn1.type import univ
    from pysnmp.proto.secmod.rfc3414 import localkey
    from pysnmp.proto.secmod.rfc3414.auth.hmacsha import HmacSha

    # RFC 3414 A.3.2: "maplesyrup", SHA, engine ID 000000000000000000000002.
    key = localkey.password_to_key_sha(univ.OctetString(b"maplesyrup"), univ.OctetString(bytes(11) + b"\x02"))
    assert key.asOctets().hex() == "6695febc9288e36282235fc7151f128497b38f3f"
    # The digest pysnmp writes into a message is HMAC-SHA1 truncated to 12 bytes (RFC 3414 7.3.1), as the
    # standard library computes it, over the message with the digest's place zeroed.
    message = b"\x30\x14" + bytes(12) + b"a message"
    signed = HmacSha().authenticate_outgoing_message(key, message)
    digest = hmac.new(key.asOctets(), message, hashlib.sha1).digest()[:12]
    assert signed == message[:2] + digest + message[14:]
    assert HmacSha().authenticate_incoming_message(key, univ.OctetString(digest), signed) == message


def test_aes_128_cfb_computes_nists_vectors_both_ways() -> None:
    from pyasn1.type import univ
    from pysnmp.proto.secmod.rfc3414 import service  # noqa: F401  (before aes: pysnmp imports them circularly)
    from pysnmp.proto.secmod.rfc3826.priv.aes import Aes

    # NIST SP 800-38A F.3.13/F.3.14, CFB128-AES128, first block; the IV is engine boots, time and salt.
    key = univ.OctetString(bytes.fromhex("2b7e151628aed2a6abf7158809cf4f3c"))
    plain, cipher = bytes.fromhex("6bc1bee22e409f96e93d7e117393172a"), bytes.fromhex("3b3fd92eb72dad20333449f8e83cfb4a")
    salt = bytes.fromhex("08090a0b0c0d0e0f")
    decrypted = Aes().decrypt_data(key, (0x00010203, 0x04050607, univ.OctetString(salt)), univ.OctetString(cipher))
    assert bytes(decrypted) == plain
    aes = Aes()
    aes.local_int = int.from_bytes(salt, "big")  # the salt pysnmp draws for its next message
    encrypted, used_salt = aes.encrypt_data(key, (0x00010203, 0x04050607, None), plain)
    assert (bytes(encrypted), bytes(used_salt)) == (cipher, salt)


def test_our_check_finds_the_services_working_here() -> None:
    assert services_missing() is None


@pytest.fixture
def without_cryptography(tmp_path: Path) -> dict[str, str]:
    """An environment whose Python cannot import cryptography (a package of that name that refuses to load,
    first on the path)."""
    shadow = tmp_path / "shadow" / "cryptography"
    shadow.mkdir(parents=True)
    (shadow / "__init__.py").write_text("raise ImportError('cryptography hidden by the test')\n")
    return {**os.environ, "PYTHONPATH": str(shadow.parent), "HILS_SNMP_AUTH_KEY": "auth-pass-phrase",
            "HILS_SNMP_PRIV_KEY": "priv-pass-phrase"}


def hils(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hils", *args], capture_output=True, text=True, timeout=60,
                          env=env)


@pytest.mark.parametrize("command", [
    ["run", "--target", "snmp://127.0.0.1:1?version=3&user=ops&auth=SHA&priv=AES", "--no-sumo", "--duration", "5"],
    ["emulator", "serve", "--port", "0", "--v3-user", "ops"],
])
def test_without_cryptography_privacy_is_refused_in_one_line(without_cryptography: dict[str, str],
                                                             command: list[str]) -> None:
    done = hils(without_cryptography, *command)
    assert done.returncode != 0
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert "SNMPv3 privacy (AES-128) does not work in this Python environment" in lines[0]
    assert f"pip install '{CRYPTOGRAPHY_NEEDED}'" in lines[0]
    assert "community" not in lines[0] and "no answer" not in lines[0]


def test_without_cryptography_authentication_alone_still_works(without_cryptography: dict[str, str]) -> None:
    code = ("from hils.shell.snmp import SnmpTarget; from hils.protocol.usm import services_missing; "
            "print(SnmpTarget.parse('snmp://h?version=3&user=ops&auth=SHA').security_level, services_missing(False))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          env=without_cryptography)
    assert done.stdout.split() == ["authNoPriv", "None"], done.stderr
