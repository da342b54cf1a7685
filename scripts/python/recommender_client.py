"""A Recommender client in Python (grpcio), built from wire/proto/jsae.proto at run time.

Usage: recommender_client.py ADDR KNOWN_ITEM [KNOWN_ITEM ...]
       recommender_client.py --ask ADDR K ITEM [ITEM ...]
       recommender_client.py --auth ADDR TOKEN_FILE CA_FILE|- KNOWN_ITEM

Checks the contract from another language: health, good and malformed sessions, good and
bad Recommend requests. Prints one JSON object with what it saw (the Rust test reads it) and
exits non-zero on the first check that fails. With --ask it only asks for the K best items
after the history ITEM... (any --policy the service serves) and prints the answer as JSON.
With --auth it checks a service started with --auth-token-file (and, given a CA file, TLS):
health answers without the token; Recommend, SubmitSessions and reflection answer
UNAUTHENTICATED without it or with another; with it Recommend answers.
"""

import json
import math
import os
import sys
import tempfile

import grpc
from grpc_tools import protoc
from grpc_health.v1 import health_pb2, health_pb2_grpc


def build_stubs(out_dir):
    proto_dir = os.path.join(os.path.dirname(__file__), "..", "..", "wire", "proto")
    proto_dir = os.path.abspath(proto_dir)
    include = os.path.join(os.path.dirname(protoc.__file__), "_proto")
    rc = protoc.main([
        "protoc", f"-I{proto_dir}", f"-I{include}", f"--python_out={out_dir}",
        f"--grpc_python_out={out_dir}", os.path.join(proto_dir, "jsae.proto"),
    ])
    if rc != 0:
        sys.exit(f"protoc failed ({rc})")
    sys.path.insert(0, out_dir)
    import jsae_pb2
    import jsae_pb2_grpc
    return jsae_pb2, jsae_pb2_grpc


def expect_code(call, code, what):
    try:
        call()
    except grpc.RpcError as e:
        if e.code() != code:
            sys.exit(f"{what}: got {e.code()} ({e.details()}), expected {code}")
        return e.details()
    sys.exit(f"{what}: succeeded, expected {code}")


def connect(addr):
    limit = 64 * 1024 * 1024
    return grpc.insecure_channel(addr, options=[
        ("grpc.max_send_message_length", limit), ("grpc.max_receive_message_length", limit)])


def ask(addr, k, history):
    pb, rpc = build_stubs(tempfile.mkdtemp(prefix="jsae-stubs-"))
    stub = rpc.RecommenderStub(connect(addr))
    r = stub.Recommend(pb.RecommendRequest(history=history, k=k), timeout=10)
    print(json.dumps({"items": [i.item_id for i in r.items], "scores": [i.score for i in r.items],
                      "policy_version": r.policy_version,
                      "embedding_version": r.embedding_version,
                      "unknown_items": r.unknown_items}))


def check_auth(addr, token_file, ca_file, item):
    pb, rpc = build_stubs(tempfile.mkdtemp(prefix="jsae-stubs-"))
    with open(token_file) as f:
        token = f.read().strip()
    if ca_file == "-":
        channel = grpc.insecure_channel(addr)
    else:
        with open(ca_file, "rb") as f:
            channel = grpc.secure_channel(addr, grpc.ssl_channel_credentials(f.read()))
    seen = {}
    health = health_pb2_grpc.HealthStub(channel)
    status = health.Check(health_pb2.HealthCheckRequest(service=""), timeout=10).status
    if status != health_pb2.HealthCheckResponse.SERVING:
        sys.exit(f"health without a token: {status}")
    seen["health"] = "SERVING"
    stub = rpc.RecommenderStub(channel)
    ask = pb.RecommendRequest(history=[item], k=1)
    session = pb.Session(session_id="auth-check", purchases=[pb.Purchase(item_id=item, price=1.0)])
    reflect = channel.stream_stream(
        "/grpc.reflection.v1.ServerReflection/ServerReflectionInfo",
        request_serializer=lambda b: b, response_deserializer=lambda b: b)
    # field 7 (list_services) = "": a valid ServerReflectionRequest
    calls = {
        "recommend": lambda md: stub.Recommend(ask, timeout=10, metadata=md),
        "submit": lambda md: stub.SubmitSessions(iter([session]), timeout=10, metadata=md),
        "reflection": lambda md: list(reflect(iter([b"\x3a\x00"]), timeout=10, metadata=md)),
    }
    unauthenticated = grpc.StatusCode.UNAUTHENTICATED
    for name, call in calls.items():
        seen[f"{name}_without_token"] = expect_code(lambda: call(None), unauthenticated, name)
        wrong = [("authorization", "Bearer " + token[:-1] + ("x" if token[-1] != "x" else "y"))]
        seen[f"{name}_wrong_token"] = expect_code(lambda: call(wrong), unauthenticated, name)
    good = [("authorization", "Bearer " + token)]
    r = calls["recommend"](good)
    if len(r.items) != 1:
        sys.exit(f"Recommend with the token: {r}")
    seen["recommend_with_token"] = r.items[0].item_id
    if not calls["reflection"](good):
        sys.exit("reflection with the token: no answer")
    seen["reflection_with_token"] = "answered"
    print(json.dumps(seen))


def main():
    if sys.argv[1] == "--ask":
        ask(sys.argv[2], int(sys.argv[3]), sys.argv[4:])
        return
    if sys.argv[1] == "--auth":
        check_auth(sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[5])
        return
    addr, known = sys.argv[1], sys.argv[2:]
    pb, rpc = build_stubs(tempfile.mkdtemp(prefix="jsae-stubs-"))
    channel = connect(addr)
    seen = {}

    health = health_pb2_grpc.HealthStub(channel)
    for service in ("", "jsae.v1.Recommender"):
        status = health.Check(health_pb2.HealthCheckRequest(service=service), timeout=10).status
        if status != health_pb2.HealthCheckResponse.SERVING:
            sys.exit(f"health of {service!r}: {status}")
    seen["health"] = "SERVING"

    stub = rpc.RecommenderStub(channel)

    # good recommendations
    r = stub.Recommend(pb.RecommendRequest(history=known, k=5), timeout=10)
    if len(r.items) != 5 or r.policy_version == 0:
        sys.exit(f"Recommend: {r}")
    scores = [i.score for i in r.items]
    if scores != sorted(scores, reverse=True) or len({i.item_id for i in r.items}) != 5:
        sys.exit(f"Recommend: items not best first or repeated: {r}")
    seen["recommend"] = {"items": [i.item_id for i in r.items], "scores": scores,
                         "policy_version": r.policy_version,
                         "embedding_version": r.embedding_version,
                         "unknown_items": r.unknown_items}
    r = stub.Recommend(pb.RecommendRequest(history=["no-such-item", known[0], "nor-this"], k=3),
                       timeout=10)
    if r.unknown_items != 2 or len(r.items) != 3:
        sys.exit(f"Recommend with unknown items: {r}")
    seen["unknown_items"] = r.unknown_items

    # bad requests
    bad = {
        "k0": pb.RecommendRequest(history=known, k=0),
        "k_above_catalogue": pb.RecommendRequest(history=known, k=10_000_000),
        "empty": pb.RecommendRequest(),
        "empty_history": pb.RecommendRequest(k=3),
        "long_history": pb.RecommendRequest(history=[known[0]] * 1001, k=3),
    }
    seen["invalid"] = {}
    for name, req in bad.items():
        seen["invalid"][name] = expect_code(lambda: stub.Recommend(req, timeout=10),
                                            grpc.StatusCode.INVALID_ARGUMENT, f"Recommend {name}")

    def session(sid, purchases):
        return pb.Session(session_id=sid, purchases=[
            pb.Purchase(item_id=i, price=p, time_unix_ms=1_700_000_000_000 + n)
            for n, (i, p) in enumerate(purchases)])

    sessions = [
        session("good-1", [(known[0], 2.5), (known[1], 4.0), ("brand-new-item", 9.99)]),
        session("", [(known[0], 1.0)]),
        session("no-purchases", []),
        session("empty-item", [(known[0], 1.0), ("", 1.0)]),
        session("negative", [(known[0], -0.01)]),
        session("nan", [(known[0], math.nan)]),
        session("inf", [(known[0], math.inf)]),
        session("good-2", [(known[1], 0.0)]),
    ]
    s = stub.SubmitSessions(iter(sessions), timeout=30)
    if (s.sessions_accepted, s.sessions_rejected, s.purchases_accepted) != (2, 6, 4):
        sys.exit(f"SubmitSessions: {s}")
    if len(s.errors) != 6 or not all("INVALID_ARGUMENT" in e for e in s.errors):
        sys.exit(f"SubmitSessions errors: {list(s.errors)}")
    seen["submit"] = {"accepted": s.sessions_accepted, "rejected": s.sessions_rejected,
                      "purchases": s.purchases_accepted, "errors": list(s.errors)}

    seen["submit_empty"] = expect_code(lambda: stub.SubmitSessions(iter([]), timeout=10),
                                       grpc.StatusCode.INVALID_ARGUMENT, "SubmitSessions empty")
    huge = session("huge", [("x" * 200, 1.0)] * 100_000)  # about 21 MB: over MAX_REQUEST_BYTES (4 MiB)
    seen["submit_huge"] = expect_code(lambda: stub.SubmitSessions(iter([huge]), timeout=30),
                                      grpc.StatusCode.RESOURCE_EXHAUSTED, "SubmitSessions huge")
    print(json.dumps(seen))


if __name__ == "__main__":
    main()
