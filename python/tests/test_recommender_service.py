"""jsae.recommender against a real `jsae recommender` process (the popular-items reference
policy on 40 synthetic items, `item-0` .. `item-39`): recommendations and session
submissions round-trip, without a token, with one (and UNAUTHENTICATED without it), and over
TLS. Skipped when no `jsae` binary is built (conftest.find_jsae_binary)."""

from __future__ import annotations

import grpc
import pytest

from jsae.channel import read_token_file
from jsae.recommender import (
    Purchase,
    Recommendation,
    Recommender,
    RecommenderError,
    ScoredItem,
    Session,
    SubmitSummary,
)

CATALOGUE = 40
T0 = 1_700_000_000_000


def assert_a_good_recommendation(answer: Recommendation, k: int) -> None:
    """k distinct catalogue items, best first."""
    assert isinstance(answer, Recommendation)
    assert len(answer.items) == k, answer
    assert all(isinstance(item, ScoredItem) for item in answer.items)
    assert len(set(answer.item_ids)) == k, answer
    assert all(i.startswith("item-") for i in answer.item_ids), answer
    scores = [item.score for item in answer.items]
    assert scores == sorted(scores, reverse=True), answer


def test_recommendations_and_sessions_round_trip(recommender_service, tmp_path) -> None:
    service = recommender_service("--store-dir", str(tmp_path / "store"))
    with Recommender(f"http://{service.address}") as rec:
        answer = rec.recommend(["item-0", "item-1"], k=5)
        assert_a_good_recommendation(answer, 5)
        assert answer.unknown_items == 0
        assert answer.policy_version >= 0 and answer.embedding_version >= 0

        with_unknown = rec.recommend(["no-such-item", "item-3", "nor-this"], k=3)
        assert_a_good_recommendation(with_unknown, 3)
        assert with_unknown.unknown_items == 2

        with pytest.raises(RecommenderError) as refused:
            rec.recommend(["item-0"], k=CATALOGUE + 1)
        assert refused.value.code == grpc.StatusCode.INVALID_ARGUMENT
        assert refused.value.details, "the service says why"

        sessions = [
            Session("py-1", [Purchase("item-0", 2.5, T0), Purchase("item-1", 4.0, T0 + 1)]),
            {"session_id": "py-2", "purchases": [{"item_id": "item-2", "price": 1}]},
            ("py-3", [("brand-new-item", 9.99, T0 + 2)]),
            Session("py-bad", [Purchase("item-0", -1.0, T0)]),  # a negative price
        ]
        summary = rec.submit_sessions(iter(sessions))
        assert isinstance(summary, SubmitSummary)
        assert (summary.sessions_accepted, summary.sessions_rejected) == (3, 1), summary
        assert summary.purchases_accepted == 4, summary
        assert summary.sessions_duplicate == 0, summary
        assert len(summary.errors) == 1 and "py-bad" in summary.errors[0], summary

        again = rec.submit_sessions(sessions[:3])
        assert (again.sessions_accepted, again.sessions_duplicate) == (0, 3), again

        with pytest.raises(RecommenderError) as refused:
            rec.submit_sessions([])
        assert refused.value.code == grpc.StatusCode.INVALID_ARGUMENT


def test_a_submission_that_fails_on_the_client_stores_nothing(
    recommender_service, tmp_path
) -> None:
    service = recommender_service("--store-dir", str(tmp_path / "store"))
    good = Session("py-kept-back", [Purchase("item-5", 1.0, T0)])

    def sessions_then_a_broken_source():
        yield good
        raise OSError("the session file went away")

    with Recommender(service.address) as rec:
        with pytest.raises(TypeError, match="session 1"):
            rec.submit_sessions([good, object()])
        with pytest.raises(OSError, match="went away"):
            rec.submit_sessions(sessions_then_a_broken_source())
        # both calls were cancelled: the good session was not stored by either
        summary = rec.submit_sessions([good])
        assert (summary.sessions_accepted, summary.sessions_duplicate) == (1, 0), summary


def test_with_a_token_calls_without_it_are_refused(recommender_service, token_file) -> None:
    service = recommender_service("--auth-token-file", str(token_file))
    token = read_token_file(token_file)
    session = Session("py-auth", [Purchase("item-0", 1.0, T0)])

    wrong = token[:-1] + ("x" if token[-1] != "x" else "y")
    for refused_token in (None, wrong):
        with Recommender(service.address, token=refused_token) as rec:
            for call in (lambda: rec.recommend(["item-0"], 1),
                         lambda: rec.submit_sessions([session])):
                with pytest.raises(RecommenderError) as refused:
                    call()
                assert refused.value.code == grpc.StatusCode.UNAUTHENTICATED, refused.value

    with Recommender(service.address, token=token) as rec:
        assert_a_good_recommendation(rec.recommend(["item-0"], 3), 3)
        summary = rec.submit_sessions([session])
        assert (summary.sessions_accepted, summary.purchases_accepted) == (1, 1), summary
    assert token not in service.stderr(), "the service logged the token"


def test_over_tls_the_client_checks_the_server_certificate(
    recommender_service, token_file, pki
) -> None:
    service = recommender_service(
        "--auth-token-file", str(token_file), "--tls-cert", str(pki.cert), "--tls-key", str(pki.key)
    )
    token = read_token_file(token_file)
    # the certificate names localhost only: by name, or by IP with tls_domain
    for addr, domain in [(f"https://localhost:{service.port}", None),
                         (f"127.0.0.1:{service.port}", "localhost")]:
        with Recommender(addr, token=token, tls_ca=pki.ca, tls_domain=domain) as rec:
            assert_a_good_recommendation(rec.recommend(["item-0", "item-7"], 4), 4)
            summary = rec.submit_sessions([("py-tls", [("item-7", 3.0, T0)])])
            assert summary.sessions_accepted + summary.sessions_duplicate == 1, summary

    # the IP is not in the certificate, and plain text does not reach a TLS server
    for kwargs in ({"tls_ca": pki.ca}, {}):
        with Recommender(f"127.0.0.1:{service.port}", token=token, timeout=10, **kwargs) as rec:
            with pytest.raises(RecommenderError) as refused:
                rec.recommend(["item-0"], 1)
            assert refused.value.code == grpc.StatusCode.UNAVAILABLE, refused.value
