"""A secret a client sent is compared as bytes and never raises, whatever the client sent; a
signature is openssl's HMAC; a secret file must hold enough."""

import shutil
import subprocess

import pytest

from shared.errors import UsageError
from shared.secret import read_secret, same_secret, signature


def test_only_the_same_string_is_the_secret():
    assert same_secret("s3cret", "s3cret")
    for given in ("s3cret ", "S3cret", "", "sécret", "\udc80", "s3cret\x00", None, 7, b"s3cret", ["s3cret"]):
        assert not same_secret(given, "s3cret")
    assert same_secret("sécret\udc80", "sécret\udc80")


def test_a_signature_is_openssls_hmac_and_a_secret_file_must_hold_enough(tmp_path):
    secret = b"a-study-secret-0123"
    assert signature(secret, "W-17") != signature(secret, "W-18") != signature(b"another-secret-0123", "W-18")
    if shutil.which("openssl"):
        printed = subprocess.run(
            ["openssl", "dgst", "-sha256", "-hmac", secret.decode()],
            input=b"W-17", capture_output=True, check=True,
        ).stdout.decode()  # fmt: skip
        assert printed.split()[-1] == signature(secret, "W-17")
    (tmp_path / "ok").write_bytes(secret + b"\n")
    assert read_secret(tmp_path / "ok", "--link-secret") == secret
    (tmp_path / "short").write_text("short\n")
    with pytest.raises(UsageError, match="short: the secret needs at least 16 characters, it has 5"):
        read_secret(tmp_path / "short", "--link-secret")
    with pytest.raises(UsageError, match="--link-secret .*none: cannot read the secret"):
        read_secret(tmp_path / "none", "--link-secret")
