"""jsae.recommender without a service: argument checks, the session and purchase forms, the
client's life cycle, and the error a call raises when nothing listens."""

from __future__ import annotations

import socket

import grpc
import numpy as np
import pytest

import jsae
from jsae.recommender import (
    Purchase,
    Recommender,
    RecommenderError,
    Session,
    purchase_message,
    recommend_request,
    session_message,
)

TOKEN = "0123456789abcdef0123"


def test_the_package_has_its_version() -> None:
    assert jsae.__version__ == "0.1.0"


def test_a_request_holds_the_history_in_order_and_k() -> None:
    request = recommend_request(("b", "a", "b"), np.int64(5))
    assert list(request.history) == ["b", "a", "b"]
    assert request.k == 5


@pytest.mark.parametrize(
    "history, k, error",
    [
        ("item-1", 3, TypeError),  # one string, not a list of ids
        (b"item-1", 3, TypeError),
        ([1, 2], 3, TypeError),  # ids are strings
        (None, 3, TypeError),
        (["a"], 0, ValueError),
        (["a"], -2, ValueError),
        (["a"], 2**32, ValueError),
        (["a"], 2.0, TypeError),
        (["a"], True, TypeError),
        (["a"], "3", TypeError),
    ],
)
def test_malformed_requests_are_refused_before_sending(history, k, error) -> None:
    with pytest.raises(error):
        recommend_request(history, k)


def test_purchases_come_as_dataclasses_dicts_or_tuples() -> None:
    want = ("i", 2.5, 1_700_000_000_000)
    for form in [
        Purchase("i", 2.5, 1_700_000_000_000),
        {"item_id": "i", "price": 2.5, "time_unix_ms": 1_700_000_000_000},
        ("i", np.float32(2.5), np.int64(1_700_000_000_000)),
    ]:
        message = purchase_message(form)
        assert (message.item_id, message.price, message.time_unix_ms) == want
    for short in [Purchase("i"), {"item_id": "i"}, ("i",)]:
        message = purchase_message(short)
        assert (message.item_id, message.price, message.time_unix_ms) == ("i", 0.0, 0)
    assert purchase_message(("i", 3)).price == 3.0


@pytest.mark.parametrize(
    "purchase, error, reason",
    [
        ({"item": "i"}, ValueError, "unknown keys"),
        ({"price": 1.0}, ValueError, "no item_id"),
        (("i", 1.0, 2, 3), ValueError, "tuple of 4"),
        ((), ValueError, "tuple of 0"),
        (["i", 1.0], TypeError, "must be a Purchase"),
        (("i", "1.0"), TypeError, "price must be a number"),
        (("i", True), TypeError, "price must be a number"),
        (("i", 1.0, 1.5), TypeError, "time_unix_ms must be an integer"),
        (("i", 1.0, 2**63), ValueError, "outside int64"),
        ((7, 1.0), TypeError, "item_id must be a string"),
    ],
)
def test_malformed_purchases_are_refused_with_the_reason(purchase, error, reason) -> None:
    with pytest.raises(error, match=reason):
        purchase_message(purchase)


def test_sessions_come_as_dataclasses_dicts_or_pairs() -> None:
    forms = [
        Session("s", [Purchase("a", 1.0), ("b", 2.0, 3)]),
        {"session_id": "s", "purchases": [{"item_id": "a", "price": 1}, ("b", 2.0, 3)]},
        ("s", [("a", 1.0), {"item_id": "b", "price": 2.0, "time_unix_ms": 3}]),
    ]
    for form in forms:
        message = session_message(form)
        assert message.session_id == "s"
        got = [(p.item_id, p.price, p.time_unix_ms) for p in message.purchases]
        assert got == [("a", 1.0, 0), ("b", 2.0, 3)]


def test_rules_of_the_service_are_left_to_the_service() -> None:
    # an empty id, no purchases or a negative price are well-typed: the service rejects
    # such a session and lists it in SubmitSummary.errors, so they are sent as they are
    message = session_message(("", [("", -1.0)]))
    assert message.session_id == "" and message.purchases[0].price == -1.0
    assert len(session_message(Session("s")).purchases) == 0


@pytest.mark.parametrize(
    "session, error, reason",
    [
        ({"id": "s", "purchases": []}, ValueError, "unknown keys"),
        ({"purchases": []}, ValueError, "no session_id"),
        (("s", "abc"), TypeError, "purchases must be a list"),
        (("s", {"item_id": "a"}), TypeError, "purchases must be a list"),
        (("s", [("a", 1.0)], 3), TypeError, "must be a Session"),
        ("s", TypeError, "must be a Session"),
        ((5, []), TypeError, "session_id must be a string"),
        (("s", [("a", "free")]), TypeError, r"session \('s'\) purchase 0: price"),
    ],
)
def test_malformed_sessions_are_refused_with_the_reason(session, error, reason) -> None:
    with pytest.raises(error, match=reason):
        session_message(session)


def test_client_arguments_are_checked_when_it_is_made() -> None:
    with pytest.raises(ValueError, match="at least 16"):
        Recommender("127.0.0.1:50060", token="short")
    with pytest.raises(ValueError, match="positive"):
        Recommender("127.0.0.1:50060", timeout=0)
    with pytest.raises(ValueError, match="needs a port"):
        Recommender("127.0.0.1")
    with pytest.raises(ValueError, match="https:// needs tls_ca"):
        Recommender("https://localhost:50060")


def test_the_client_never_shows_its_token() -> None:
    with Recommender("127.0.0.1:50060", token=TOKEN) as rec:
        assert TOKEN not in repr(rec) and "token=set" in repr(rec)


def test_a_closed_client_refuses_calls_and_closes_once() -> None:
    with Recommender("127.0.0.1:50060") as rec:
        pass
    assert "closed" in repr(rec)
    with pytest.raises(ValueError, match="closed"):
        rec.recommend(["a"], 1)
    with pytest.raises(ValueError, match="closed"):
        rec.submit_sessions([Session("s", [Purchase("a")])])
    rec.close()


def test_sessions_are_an_iterable_of_sessions() -> None:
    with Recommender("127.0.0.1:50060") as rec:
        for wrong in ["s", Session("s", [Purchase("a")]), {"session_id": "s"}, 5]:
            with pytest.raises(TypeError, match="iterable of sessions"):
                rec.submit_sessions(wrong)  # type: ignore[arg-type]


def _port_nothing_listens_on() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_call_nothing_answers_raises_a_recommender_error() -> None:
    with Recommender(f"127.0.0.1:{_port_nothing_listens_on()}", timeout=10) as rec:
        with pytest.raises(RecommenderError) as raised:
            rec.recommend(["a"], 1)
        assert raised.value.rpc == "Recommend"
        assert raised.value.code == grpc.StatusCode.UNAVAILABLE
        assert str(raised.value).startswith("Recommend: UNAVAILABLE: ")
        with pytest.raises(RecommenderError) as raised:
            rec.submit_sessions([Session("s", [Purchase("a")])])
        assert raised.value.code == grpc.StatusCode.UNAVAILABLE
