"""The gRPC stubs of wire/proto/jsae.proto (package `jsae.v1`), generated at build time.

`jsae_pb2` holds the messages and `jsae_pb2_grpc` the service stubs. setup.py writes both
here when the package is built (they are not kept in git); use them through the typed
clients (`jsae.recommender`) rather than directly.
"""

try:
    from . import jsae_pb2, jsae_pb2_grpc
except ImportError as e:  # a source checkout that was never built
    if e.name is not None and not e.name.startswith(__name__):
        raise
    raise ImportError(
        "jsae's gRPC stubs (jsae/_proto/jsae_pb2*.py) are missing: they are generated when "
        "the package is built, so install it (`pip install ./python` from the repository "
        "root) instead of importing the source tree"
    ) from e

__all__ = ["jsae_pb2", "jsae_pb2_grpc"]
