"""How a client reaches a JSAE-RL service: address forms, TLS and the bearer token.

The rules are the Rust clients' (net/src/security.rs), so one deployment's settings work in
both languages:

- An address is `host:port`, `http://host:port` or `https://host:port`; an IPv6 host goes in
  brackets (`[::1]:50060`). A port is required.
- `tls_ca` (a PEM file of the CA that signed the server's certificate) makes the channel TLS.
  An `https://` address needs it, and with it an `http://` address is refused: nothing falls
  back to plain text. `tls_domain` (with `tls_ca` only) is the name the server's certificate
  is checked against when it differs from the host (e.g. connecting to an IP address).
- A token (the deployment's `--auth-token-file`) travels on every call as
  `authorization: Bearer TOKEN` metadata. Services accept only tokens of at least 16 visible
  ASCII characters, so shorter ones are refused here, before anything is sent.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from numbers import Real
from typing import Any, List, Optional, Tuple, Union

import grpc

#: The shortest token the services accept, in characters (jsae_net's `MIN_TOKEN_BYTES`).
MIN_TOKEN_CHARS = 16

#: The largest message a client receives, in bytes (a `Recommend` answer with `k` near the
#: size of a large catalogue is bigger than gRPC's default of 4 MiB).
MAX_RECEIVE_BYTES = 64 * 1024 * 1024

#: The metadata key the token travels in.
AUTHORIZATION = "authorization"

_SCHEME = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]*)://(.*)$", re.DOTALL)
_BAD_HOST_CHARS = re.compile(r"[\s/@?#\[\]]")

PathLike = Union[str, "os.PathLike[str]"]


@dataclass(frozen=True)
class Address:
    """A parsed service address.

    Attributes:
        host: host name or IP address (an IPv6 address without its brackets).
        port: TCP port, 1 to 65535.
        scheme: "http" or "https" when the address was a URL, None for `host:port`.
    """

    host: str
    port: int
    scheme: Optional[str] = None

    @property
    def target(self) -> str:
        """The `host:port` gRPC connects to (an IPv6 host in brackets)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"


def parse_address(addr: str) -> Address:
    """Parses `host:port`, `http://host:port` or `https://host:port` (one trailing `/`
    allowed). Raises TypeError for a non-string, ValueError for anything else malformed."""
    if not isinstance(addr, str):
        raise TypeError(f"the address must be a string, not {type(addr).__name__}")
    text = addr.strip()
    scheme = None
    url = _SCHEME.match(text)
    if url:
        scheme, text = url.group(1).lower(), url.group(2)
        if scheme not in ("http", "https"):
            raise ValueError(f"address {addr!r}: the scheme must be http or https")
        if text.endswith("/"):
            text = text[:-1]
    if text.startswith("["):
        end = text.find("]")
        if end < 0:
            raise ValueError(f"address {addr!r}: an IPv6 host has no closing bracket")
        host, rest = text[1:end], text[end + 1 :]
        if not rest.startswith(":"):
            raise ValueError(f"address {addr!r}: needs a port (host:port)")
        port_text = rest[1:]
    else:
        host, colon, port_text = text.rpartition(":")
        if not colon:
            raise ValueError(f"address {addr!r}: needs a port (host:port)")
        if ":" in host:
            raise ValueError(f"address {addr!r}: put an IPv6 host in brackets ([::1]:50060)")
    if not host or _BAD_HOST_CHARS.search(host):
        raise ValueError(f"address {addr!r}: not a host name or IP address")
    if not port_text.isascii() or not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ValueError(f"address {addr!r}: the port must be a number from 1 to 65535")
    return Address(host=host, port=int(port_text), scheme=scheme)


def check_token(token: str) -> str:
    """The token as it travels (surrounding whitespace removed). Raises TypeError for a
    non-string and ValueError for a token no service accepts: shorter than
    `MIN_TOKEN_CHARS`, or with characters other than visible ASCII."""
    if not isinstance(token, str):
        raise TypeError(f"the token must be a string, not {type(token).__name__}")
    text = token.strip()
    if len(text) < MIN_TOKEN_CHARS:
        raise ValueError(
            f"the token has {len(text)} characters; services need at least {MIN_TOKEN_CHARS}"
        )
    if not all("!" <= c <= "~" for c in text):
        raise ValueError("the token must be visible ASCII characters without spaces")
    return text


def read_token_file(path: PathLike) -> str:
    """Reads a token file (the services' `--auth-token-file`: one line) and checks it as
    `check_token` does."""
    with open(path, encoding="ascii", errors="replace") as f:
        return check_token(f.read())


def auth_metadata(token: Optional[str]) -> Tuple[Tuple[str, str], ...]:
    """The call metadata carrying `token` (`authorization: Bearer TOKEN`); empty for None."""
    if token is None:
        return ()
    return ((AUTHORIZATION, f"Bearer {check_token(token)}"),)


def check_timeout(timeout: float, what: str = "timeout") -> float:
    """`timeout` in seconds as a float; raises unless it is a positive finite number."""
    if isinstance(timeout, bool) or not isinstance(timeout, Real):
        raise TypeError(f"{what} must be a number of seconds, not {type(timeout).__name__}")
    seconds = float(timeout)
    if not math.isfinite(seconds) or seconds <= 0:
        raise ValueError(f"{what} must be a positive number of seconds, not {timeout!r}")
    return seconds


def _read_ca(tls_ca: PathLike) -> bytes:
    with open(tls_ca, "rb") as f:
        pem = f.read()
    if b"-----BEGIN CERTIFICATE-----" not in pem:
        raise ValueError(f"tls_ca {os.fspath(tls_ca)!r} holds no PEM certificate")
    return pem


def open_channel(
    addr: str,
    tls_ca: Optional[PathLike] = None,
    tls_domain: Optional[str] = None,
) -> Tuple[grpc.Channel, Address]:
    """Opens a channel to `addr` under the rules above (TLS when `tls_ca` is given) and
    returns it with the parsed address. The channel connects lazily, on the first call.

    Raises TypeError or ValueError for an invalid address or combination, and OSError when
    `tls_ca` cannot be read.
    """
    address = parse_address(addr)
    if tls_domain is not None:
        if not isinstance(tls_domain, str) or not tls_domain.strip():
            raise ValueError("tls_domain must be a non-empty host name")
        if tls_ca is None:
            raise ValueError("tls_domain needs tls_ca (it names the server's certificate)")
    options: List[Tuple[str, Any]] = [("grpc.max_receive_message_length", MAX_RECEIVE_BYTES)]
    if tls_ca is None:
        if address.scheme == "https":
            raise ValueError(
                f"address {addr!r}: https:// needs tls_ca (the CA that signed the server's "
                "certificate)"
            )
        return grpc.insecure_channel(address.target, options=options), address
    if address.scheme == "http":
        raise ValueError(
            f"address {addr!r}: http:// is plain text, but tls_ca asks for TLS; use https:// "
            "or host:port"
        )
    credentials = grpc.ssl_channel_credentials(root_certificates=_read_ca(tls_ca))
    if tls_domain is not None:
        options.append(("grpc.ssl_target_name_override", tls_domain.strip()))
    return grpc.secure_channel(address.target, credentials, options=options), address
