"""The embedder's and the learner's token check, seen from Python (grpcio):

    services_auth_check.py EMBEDDER_ADDR LEARNER_ADDR TOKEN_FILE

Both services were started with --auth-token-file. For every RPC of jsae.v1.Embedder and
jsae.v1.Learner, and for reflection on each, a call without the token and one with another
token must answer UNAUTHENTICATED; health must answer SERVING without it; a call with the token
must get past the check (any answer but UNAUTHENTICATED). Prints one JSON object with what it
saw and exits non-zero on the first check that fails.
"""

import json
import sys
import tempfile

import grpc
from grpc_health.v1 import health_pb2, health_pb2_grpc

from recommender_client import build_stubs

UNAUTHENTICATED = grpc.StatusCode.UNAUTHENTICATED


def outcome(call):
    """The status code a call ends with ("OK" when it answers)."""
    try:
        call()
    except grpc.RpcError as e:
        return e.code().name
    return "OK"


def first(stream):
    """The first message of a server stream (or its error)."""
    return next(iter(stream))


def rpcs(pb, rpc, channel, service):
    reflect = channel.stream_stream(
        "/grpc.reflection.v1.ServerReflection/ServerReflectionInfo",
        request_serializer=lambda b: b, response_deserializer=lambda b: b)
    # field 7 (list_services) = "": a valid ServerReflectionRequest
    calls = {"reflection": lambda md: first(reflect(iter([b"\x3a\x00"]), timeout=5, metadata=md))}
    if service == "embedder":
        stub = rpc.EmbedderStub(channel)
        calls["PushTransitions"] = lambda md: stub.PushTransitions(
            iter([]), timeout=5, metadata=md)
        calls["WatchEmbedding"] = lambda md: first(stub.WatchEmbedding(
            pb.WatchRequest(), timeout=2, metadata=md))
        calls["HoldEmbedding"] = lambda md: stub.HoldEmbedding(
            pb.HoldRequest(), timeout=5, metadata=md)
    else:
        stub = rpc.LearnerStub(channel)
        calls["PushFragments"] = lambda md: stub.PushFragments(iter([]), timeout=5, metadata=md)
        calls["WatchPolicy"] = lambda md: first(stub.WatchPolicy(
            pb.WatchRequest(actor_id=1, evaluates=True), timeout=2, metadata=md))
        calls["ReportEval"] = lambda md: stub.ReportEval(
            pb.EvalReport(actor_id=1, request_id=1), timeout=5, metadata=md)
    return calls


def check(pb, rpc, addr, service, token, seen):
    channel = grpc.insecure_channel(addr)
    grpc.channel_ready_future(channel).result(timeout=60)
    health = health_pb2_grpc.HealthStub(channel)
    status = health.Check(health_pb2.HealthCheckRequest(service=""), timeout=10).status
    if status != health_pb2.HealthCheckResponse.SERVING:
        sys.exit(f"{service} health without a token: {status}")
    seen[f"{service}/health"] = "SERVING"
    wrong = token[:-1] + ("x" if token[-1] != "x" else "y")
    for name, call in rpcs(pb, rpc, channel, service).items():
        key = f"{service}/{name}"
        for label, md in [("without_token", None),
                          ("wrong_token", [("authorization", "Bearer " + wrong)])]:
            code = outcome(lambda: call(md))
            if code != UNAUTHENTICATED.name:
                sys.exit(f"{key} {label}: {code}, expected UNAUTHENTICATED")
            seen[f"{key} {label}"] = code
        code = outcome(lambda: call([("authorization", "Bearer " + token)]))
        if code == UNAUTHENTICATED.name:
            sys.exit(f"{key} with the token: UNAUTHENTICATED")
        seen[f"{key} with_token"] = code


def main():
    embedder, learner, token_file = sys.argv[1:4]
    with open(token_file) as f:
        token = f.read().strip()
    pb, rpc = build_stubs(tempfile.mkdtemp(prefix="jsae-stubs-"))
    seen = {}
    check(pb, rpc, embedder, "embedder", token, seen)
    check(pb, rpc, learner, "learner", token, seen)
    print(json.dumps(seen))


if __name__ == "__main__":
    main()
