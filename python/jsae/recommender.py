"""A typed client of the Recommender service (`jsae.v1.Recommender`, wire/proto/jsae.proto).

    from jsae.recommender import Purchase, Recommender, Session

    with Recommender("127.0.0.1:50060") as rec:
        answer = rec.recommend(["24852", "13176"], k=5)
        for item in answer.items:               # best first
            print(item.item_id, item.score)
        summary = rec.submit_sessions([
            Session("s1", [Purchase("24852", price=3.5, time_unix_ms=1_700_000_000_000)]),
        ])
        print(summary.sessions_accepted, summary.errors)

The design, in short:

- `recommend` returns a `Recommendation`: the `items` (`ScoredItem`: `item_id`, `score`, best
  first) together with the `policy_version` and `embedding_version` that produced them and
  the number of `unknown_items` in the history (ignored by the service).
- `submit_sessions` streams any iterable of sessions in one call and returns the service's
  `SubmitSummary`. A session is a `Session`, a dict in the session store's JSON shape
  (`{"session_id": ..., "purchases": [{"item_id": ..., "price": ..., "time_unix_ms": ...}]}`,
  price and time optional: 0) or a `(session_id, purchases)` pair; a purchase is a `Purchase`,
  such a dict or an `(item_id[, price[, time_unix_ms]])` tuple.
- Arguments of the wrong type or shape raise TypeError or ValueError before anything is sent.
  The service's own rules (limits on `k` and the history, malformed sessions, sizes) are
  checked by the service only: what it refuses raises `RecommenderError` with the gRPC code
  and the service's message, and a malformed session is rejected by the service and listed in
  `SubmitSummary.errors` while the call goes on (docs/src/recommender.md).
- A call stores its sessions all or none: when `submit_sessions` raises (the service refused
  the call, a session could not be converted, the iterable raised, the call was interrupted)
  the call was cancelled or refused and nothing of it was stored; send it again. Sessions are
  stored once per `session_id`, so sending a call again is safe.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from numbers import Integral, Real
from typing import Any, Iterator, List, Optional, Sequence, Tuple, Union

import grpc

from jsae._proto import jsae_pb2, jsae_pb2_grpc
from jsae.channel import PathLike, auth_metadata, check_timeout, open_channel

#: The default deadline of each call, in seconds.
DEFAULT_TIMEOUT_S = 10.0

_MAX_K = 2**32 - 1  # `k` is a uint32


class RecommenderError(Exception):
    """The service (or the transport to it) ended a call with an error.

    Attributes:
        rpc: the call, "Recommend" or "SubmitSessions".
        code: the gRPC status code (`grpc.StatusCode`), e.g. INVALID_ARGUMENT,
            RESOURCE_EXHAUSTED, UNAUTHENTICATED, UNAVAILABLE or DEADLINE_EXCEEDED.
        details: the service's message.
    """

    def __init__(self, rpc: str, code: grpc.StatusCode, details: str) -> None:
        super().__init__(f"{rpc}: {code.name}: {details}")
        self.rpc = rpc
        self.code = code
        self.details = details

    @classmethod
    def from_rpc_error(cls, rpc: str, error: grpc.RpcError) -> "RecommenderError":
        """The error a failed gRPC call raised, as a RecommenderError."""
        code = error.code() if callable(getattr(error, "code", None)) else None
        details = error.details() if callable(getattr(error, "details", None)) else None
        return cls(rpc, code or grpc.StatusCode.UNKNOWN, details or str(error))


@dataclass(frozen=True)
class ScoredItem:
    """One recommended item: its id and the policy's score (higher is better)."""

    item_id: str
    score: float


@dataclass(frozen=True)
class Recommendation:
    """The answer to `Recommender.recommend`.

    Attributes:
        items: the recommended items, best first (`k` of them).
        policy_version: the version of the policy that chose them.
        embedding_version: the version of the action embedding it used (0 without one).
        unknown_items: how many entries of the history the service did not know (ignored).
    """

    items: List[ScoredItem]
    policy_version: int
    embedding_version: int
    unknown_items: int

    @property
    def item_ids(self) -> List[str]:
        """The ids of `items`, best first."""
        return [item.item_id for item in self.items]


@dataclass(frozen=True)
class Purchase:
    """One purchase of a session: the item, its price and when (Unix milliseconds)."""

    item_id: str
    price: float = 0.0
    time_unix_ms: int = 0


@dataclass(frozen=True)
class Session:
    """A shopping session: its id (stored once per id) and its purchases, oldest first.

    `purchases` may hold `Purchase` values, dicts or tuples (see the module's docstring).
    """

    session_id: str
    purchases: Sequence[Any] = field(default_factory=list)


@dataclass(frozen=True)
class SubmitSummary:
    """The service's account of a `submit_sessions` call.

    Attributes:
        sessions_accepted: sessions stored by this call.
        sessions_rejected: malformed sessions (not stored; the count is exact).
        purchases_accepted: purchases of the stored sessions.
        errors: why sessions were rejected, one line each (at most 100 listed).
        sessions_duplicate: well-formed sessions not stored because their id was stored
            already or came earlier in the call (not an error; 0 without a session store).
    """

    sessions_accepted: int
    sessions_rejected: int
    purchases_accepted: int
    errors: List[str]
    sessions_duplicate: int


SessionLike = Union[Session, Mapping[str, Any], Tuple[str, Sequence[Any]]]


def _check_str(value: Any, what: str) -> str:
    if not isinstance(value, str):
        raise TypeError(f"{what} must be a string, not {type(value).__name__}")
    return value


def _check_price(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, Real):
        raise TypeError(f"{what} must be a number, not {type(value).__name__}")
    return float(value)


def _check_time(value: Any, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, Integral):
        raise TypeError(f"{what} must be an integer (Unix ms), not {type(value).__name__}")
    if not -(2**63) <= int(value) < 2**63:
        raise ValueError(f"{what} {int(value)} is outside int64")
    return int(value)


def _fields_of(value: Mapping[str, Any], allowed: Tuple[str, ...], what: str) -> None:
    unknown = sorted(set(value) - set(allowed))
    if unknown:
        raise ValueError(f"{what} has unknown keys {unknown} (expected {list(allowed)})")


def purchase_message(purchase: Any, what: str = "purchase") -> "jsae_pb2.Purchase":
    """A purchase (`Purchase`, dict or `(item_id[, price[, time_unix_ms]])` tuple) as the
    wire message. Raises TypeError or ValueError, naming `what`, for any other shape."""
    if isinstance(purchase, Purchase):
        item_id, price, time = purchase.item_id, purchase.price, purchase.time_unix_ms
    elif isinstance(purchase, Mapping):
        _fields_of(purchase, ("item_id", "price", "time_unix_ms"), what)
        if "item_id" not in purchase:
            raise ValueError(f"{what} has no item_id")
        item_id = purchase["item_id"]
        price, time = purchase.get("price", 0.0), purchase.get("time_unix_ms", 0)
    elif isinstance(purchase, tuple):
        if not 1 <= len(purchase) <= 3:
            raise ValueError(
                f"{what} is a tuple of {len(purchase)}, not (item_id[, price[, time_unix_ms]])"
            )
        item_id, price, time = purchase + (0.0, 0)[len(purchase) - 1 :]
    else:
        raise TypeError(
            f"{what} must be a Purchase, a dict or an (item_id, price, time_unix_ms) tuple, "
            f"not {type(purchase).__name__}"
        )
    return jsae_pb2.Purchase(
        item_id=_check_str(item_id, f"{what}: item_id"),
        price=_check_price(price, f"{what}: price"),
        time_unix_ms=_check_time(time, f"{what}: time_unix_ms"),
    )


def session_message(session: Any, what: str = "session") -> "jsae_pb2.Session":
    """A session (`Session`, dict or `(session_id, purchases)` pair) as the wire message.
    Raises TypeError or ValueError, naming `what`, for any other shape."""
    if isinstance(session, Session):
        session_id, purchases = session.session_id, session.purchases
    elif isinstance(session, Mapping):
        _fields_of(session, ("session_id", "purchases"), what)
        if "session_id" not in session:
            raise ValueError(f"{what} has no session_id")
        session_id, purchases = session["session_id"], session.get("purchases", [])
    elif isinstance(session, tuple) and len(session) == 2:
        session_id, purchases = session
    else:
        raise TypeError(
            f"{what} must be a Session, a dict or a (session_id, purchases) pair, not "
            f"{type(session).__name__}"
        )
    _check_str(session_id, f"{what}: session_id")
    if isinstance(purchases, (str, bytes, Mapping)) or not isinstance(purchases, Iterable):
        raise TypeError(f"{what} ({session_id!r}): purchases must be a list of purchases")
    return jsae_pb2.Session(
        session_id=session_id,
        purchases=[
            purchase_message(p, f"{what} ({session_id!r}) purchase {n}")
            for n, p in enumerate(purchases)
        ],
    )


def recommend_request(history: Iterable[str], k: int) -> "jsae_pb2.RecommendRequest":
    """The request for the `k` best items after `history` (item ids, oldest first). Raises
    TypeError or ValueError for a malformed history or `k` outside 1..2^32-1."""
    if isinstance(history, (str, bytes)) or not isinstance(history, Iterable):
        raise TypeError("history must be a list of item ids (strings), oldest first")
    ids = [_check_str(item, f"history[{n}]") for n, item in enumerate(history)]
    if isinstance(k, bool) or not isinstance(k, Integral):
        raise TypeError(f"k must be an integer, not {type(k).__name__}")
    if not 1 <= int(k) <= _MAX_K:
        raise ValueError(f"k must be at least 1 (and fit in 32 bits), not {k}")
    return jsae_pb2.RecommendRequest(history=ids, k=int(k))


class Recommender:
    """A client of one Recommender service.

    Args:
        addr: `host:port`, `http://host:port` or `https://host:port` (see `jsae.channel`).
        token: the deployment's shared token (its `--auth-token-file`'s contents), sent on
            every call as `authorization: Bearer TOKEN`; None sends none.
        tls_ca: PEM file of the CA that signed the server's certificate: the channel is TLS.
        tls_domain: the name to check the server's certificate against, when it is not the
            address's host (needs `tls_ca`).
        timeout: each call's default deadline in seconds (a method's `timeout` overrides it).

    The channel connects on the first call. Use the client as a context manager, or call
    `close()`; calling a closed client raises ValueError. One client may be shared between
    threads.
    """

    def __init__(
        self,
        addr: str,
        token: Optional[str] = None,
        tls_ca: Optional[PathLike] = None,
        tls_domain: Optional[str] = None,
        timeout: float = DEFAULT_TIMEOUT_S,
    ) -> None:
        self._closed = True
        self._timeout = check_timeout(timeout)
        self._metadata = auth_metadata(token)
        self._channel, self._address = open_channel(addr, tls_ca=tls_ca, tls_domain=tls_domain)
        self._tls = tls_ca is not None
        self._stub = jsae_pb2_grpc.RecommenderStub(self._channel)
        self._closed = False

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return (
            f"Recommender({self._address.target!r}, tls={self._tls}, "
            f"token={'set' if self._metadata else 'none'}, {state})"
        )

    def __enter__(self) -> "Recommender":
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def close(self) -> None:
        """Closes the channel (cancelling calls in progress). Closing again does nothing."""
        if not self._closed:
            self._closed = True
            self._channel.close()

    def _deadline(self, timeout: Optional[float]) -> float:
        if self._closed:
            raise ValueError("the Recommender client is closed")
        return self._timeout if timeout is None else check_timeout(timeout)

    def recommend(
        self, history: Iterable[str], k: int, timeout: Optional[float] = None
    ) -> Recommendation:
        """The `k` best items after `history` (item ids, oldest first).

        Returns a `Recommendation`: `items` best first, with the policy and embedding
        versions that chose them and how many history entries were unknown. Raises
        TypeError or ValueError for malformed arguments, and `RecommenderError` when the
        service refuses (e.g. INVALID_ARGUMENT for `k` above the catalogue size or a history
        over its limit, UNAVAILABLE before its first policy, UNAUTHENTICATED without the
        deployment's token).
        """
        request = recommend_request(history, k)
        deadline = self._deadline(timeout)
        try:
            reply = self._stub.Recommend(request, timeout=deadline, metadata=self._metadata)
        except grpc.RpcError as e:
            raise RecommenderError.from_rpc_error("Recommend", e) from None
        return Recommendation(
            items=[ScoredItem(item_id=i.item_id, score=i.score) for i in reply.items],
            policy_version=reply.policy_version,
            embedding_version=reply.embedding_version,
            unknown_items=reply.unknown_items,
        )

    def submit_sessions(
        self, sessions: Iterable[SessionLike], timeout: Optional[float] = None
    ) -> SubmitSummary:
        """Streams `sessions` to the service in one call and returns its `SubmitSummary`.

        The iterable is read lazily, as the call sends. Malformed sessions (an empty id, no
        purchases, an empty item id, a bad price) are rejected by the service and listed in
        the summary's `errors`; the rest are stored when the stream ends. The call is one
        call under the service's limits (at most 100,000 sessions and 64 MiB; an empty
        iterable is INVALID_ARGUMENT): past them it raises `RecommenderError`
        (RESOURCE_EXHAUSTED) and nothing is stored, so split larger inputs into several calls.

        If a session cannot be converted (TypeError, ValueError) or the iterable itself
        raises, the call is cancelled, nothing of it is stored and that exception is raised.
        """
        if isinstance(sessions, (str, bytes, Mapping, Session)) or not isinstance(
            sessions, Iterable
        ):
            raise TypeError("sessions must be an iterable of sessions")
        deadline = self._deadline(timeout)
        source = iter(sessions)
        failure: List[BaseException] = []
        call_started = threading.Event()
        call_box: List[grpc.Future] = []

        def messages() -> Iterator["jsae_pb2.Session"]:
            # Runs on gRPC's sending thread. On a failure the call is cancelled rather than
            # ended: a stream that ends cleanly would commit the sessions sent before it.
            for n in itertools.count():
                try:
                    message = session_message(next(source), f"session {n}")
                except StopIteration:
                    return
                except Exception as e:  # noqa: BLE001 (raised again on the caller's thread)
                    failure.append(e)
                    break
                yield message
            call_started.wait()
            if call_box:
                call_box[0].cancel()

        try:
            call = self._stub.SubmitSessions.future(
                messages(), timeout=deadline, metadata=self._metadata
            )
            call_box.append(call)
        finally:
            call_started.set()
        try:
            reply = call.result()
        except grpc.FutureCancelledError:
            if failure:
                raise failure[0] from None
            cancelled = RecommenderError("SubmitSessions", grpc.StatusCode.CANCELLED, "cancelled")
            raise cancelled from None
        except grpc.RpcError as e:
            if failure:
                raise failure[0] from None
            raise RecommenderError.from_rpc_error("SubmitSessions", e) from None
        except BaseException:
            call.cancel()  # e.g. KeyboardInterrupt: a cancelled call stores nothing
            raise
        return SubmitSummary(
            sessions_accepted=reply.sessions_accepted,
            sessions_rejected=reply.sessions_rejected,
            purchases_accepted=reply.purchases_accepted,
            errors=list(reply.errors),
            sessions_duplicate=reply.sessions_duplicate,
        )
