"""jsae.channel without a server: address forms, the token rule, TLS combinations, timeouts."""

from __future__ import annotations

import pytest

from jsae.channel import (
    Address,
    auth_metadata,
    check_timeout,
    check_token,
    open_channel,
    parse_address,
    read_token_file,
)

TOKEN = "0123456789abcdef0123"


@pytest.mark.parametrize(
    "text, expected",
    [
        ("127.0.0.1:50060", Address("127.0.0.1", 50060, None)),
        ("localhost:1", Address("localhost", 1, None)),
        ("http://recommender.internal:50060", Address("recommender.internal", 50060, "http")),
        ("HTTPS://localhost:443/", Address("localhost", 443, "https")),
        ("[::1]:50060", Address("::1", 50060, None)),
        ("https://[fe80::1]:65535", Address("fe80::1", 65535, "https")),
        ("  127.0.0.1:8080\n", Address("127.0.0.1", 8080, None)),
    ],
)
def test_addresses_parse_into_host_port_and_scheme(text: str, expected: Address) -> None:
    assert parse_address(text) == expected


def test_the_target_puts_an_ipv6_host_in_brackets() -> None:
    assert parse_address("http://[::1]:7").target == "[::1]:7"
    assert parse_address("http://localhost:7/").target == "localhost:7"


@pytest.mark.parametrize(
    "text, reason",
    [
        ("localhost", "needs a port"),
        ("http://localhost", "needs a port"),
        ("localhost:", "port must be"),
        ("localhost:0", "port must be"),
        ("localhost:65536", "port must be"),
        ("localhost:5o", "port must be"),
        ("localhost:+80", "port must be"),
        (":50060", "not a host"),
        ("ftp://localhost:21", "scheme must be http or https"),
        ("::1:50060", "brackets"),
        ("[::1:50060", "closing bracket"),
        ("[::1]", "needs a port"),
        ("http://localhost:50060/path", "port must be"),
        ("user@localhost:50060", "not a host"),
        ("local host:50060", "not a host"),
    ],
)
def test_malformed_addresses_are_refused_with_the_reason(text: str, reason: str) -> None:
    with pytest.raises(ValueError, match=reason):
        parse_address(text)


def test_an_address_must_be_a_string() -> None:
    with pytest.raises(TypeError):
        parse_address(("localhost", 50060))  # type: ignore[arg-type]


def test_a_token_travels_as_bearer_metadata_without_surrounding_whitespace() -> None:
    assert auth_metadata(None) == ()
    assert auth_metadata(f"  {TOKEN}\n") == (("authorization", f"Bearer {TOKEN}"),)


@pytest.mark.parametrize(
    "token, reason",
    [
        ("short-token", "at least 16"),
        ("", "at least 16"),
        ("0123456789 abcdef0123", "visible ASCII"),
        ("0123456789abcdef012\u00e9", "visible ASCII"),
    ],
)
def test_tokens_no_service_accepts_are_refused_before_sending(token: str, reason: str) -> None:
    with pytest.raises(ValueError, match=reason):
        check_token(token)


def test_a_token_must_be_a_string() -> None:
    with pytest.raises(TypeError):
        check_token(TOKEN.encode())  # type: ignore[arg-type]


def test_a_token_file_is_read_as_the_services_read_it(tmp_path) -> None:
    path = tmp_path / "token"
    path.write_text(TOKEN + "\n")
    assert read_token_file(path) == TOKEN
    path.write_text("too short\n")
    with pytest.raises(ValueError):
        read_token_file(path)


def test_https_needs_a_ca() -> None:
    with pytest.raises(ValueError, match="https:// needs tls_ca"):
        open_channel("https://localhost:50060")


def test_a_ca_refuses_plain_text_http(tmp_path) -> None:
    ca = tmp_path / "ca.pem"
    ca.write_text("-----BEGIN CERTIFICATE-----\nAAAA\n-----END CERTIFICATE-----\n")
    with pytest.raises(ValueError, match="plain text"):
        open_channel("http://localhost:50060", tls_ca=ca)


def test_tls_domain_needs_a_ca() -> None:
    with pytest.raises(ValueError, match="tls_domain needs tls_ca"):
        open_channel("127.0.0.1:50060", tls_domain="localhost")


def test_a_ca_file_must_exist_and_hold_a_pem_certificate(tmp_path) -> None:
    with pytest.raises(FileNotFoundError):
        open_channel("localhost:50060", tls_ca=tmp_path / "missing.pem")
    not_pem = tmp_path / "key.txt"
    not_pem.write_text("not a certificate")
    with pytest.raises(ValueError, match="no PEM certificate"):
        open_channel("localhost:50060", tls_ca=not_pem)


def test_channels_open_lazily_for_each_allowed_combination(tmp_path) -> None:
    ca = tmp_path / "ca.pem"
    ca.write_text("-----BEGIN CERTIFICATE-----\nAAAA\n-----END CERTIFICATE-----\n")
    for addr, kwargs in [
        ("127.0.0.1:9", {}),
        ("http://127.0.0.1:9", {}),
        ("https://localhost:9", {"tls_ca": ca}),
        ("127.0.0.1:9", {"tls_ca": str(ca), "tls_domain": "localhost"}),
    ]:
        channel, address = open_channel(addr, **kwargs)
        assert address.port == 9
        channel.close()


@pytest.mark.parametrize("value", [0, -1, float("nan"), float("inf")])
def test_timeouts_must_be_positive_and_finite(value: float) -> None:
    with pytest.raises(ValueError):
        check_timeout(value)


def test_timeouts_are_numbers_of_seconds() -> None:
    assert check_timeout(2) == 2.0
    with pytest.raises(TypeError):
        check_timeout("10")  # type: ignore[arg-type]
    with pytest.raises(TypeError):
        check_timeout(True)
