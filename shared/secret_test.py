"""A secret a client sent is compared as bytes and never raises, whatever the client sent."""

from shared.secret import same_secret


def test_only_the_same_string_is_the_secret():
    assert same_secret("s3cret", "s3cret")
    for given in ("s3cret ", "S3cret", "", "sécret", "\udc80", "s3cret\x00", None, 7, b"s3cret", ["s3cret"]):
        assert not same_secret(given, "s3cret")
    assert same_secret("sécret\udc80", "sécret\udc80")
