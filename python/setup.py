"""Builds the `jsae` package, generating its gRPC stubs from the project's proto first.

The metadata lives in pyproject.toml; this file only adds a `build_py` step that runs
grpc_tools.protoc on ../wire/proto/jsae.proto (relative to this directory) and writes
jsae/_proto/jsae_pb2.py, jsae_pb2.pyi and jsae_pb2_grpc.py into the source tree (git ignores
them), so that regular and editable installs both ship them. pip builds a local directory in
place (pip 21.3 and later), which is what lets the relative path reach the proto.
"""

import re
import sys
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent
PROTO_DIR = HERE.parent / "wire" / "proto"
PROTO_FILE = "jsae.proto"
STUBS_DIR = HERE / "jsae" / "_proto"

# protoc writes the gRPC module's import of the messages as a top-level import; inside the
# package it has to be relative.
TOP_LEVEL_IMPORT = re.compile(r"^import jsae_pb2 as ", re.MULTILINE)


def generate_stubs() -> None:
    """Runs protoc on the proto and makes the generated gRPC module import its messages
    relatively; exits with a clear message when the proto or protoc fails."""
    proto = PROTO_DIR / PROTO_FILE
    if not proto.is_file():
        sys.exit(
            f"jsae: {proto} not found. The package is built from a JSAE-RL checkout, whose "
            "wire/proto/ holds the protocol: `pip install ./python` in the repository root "
            "(pip 21.3 or later builds the directory in place, so ../wire/proto is reachable)."
        )
    from grpc_tools import protoc  # a build requirement (pyproject.toml)

    well_known = Path(protoc.__file__).resolve().parent / "_proto"
    args = [
        "grpc_tools.protoc",
        f"-I{PROTO_DIR}",
        f"-I{well_known}",
        f"--python_out={STUBS_DIR}",
        f"--pyi_out={STUBS_DIR}",
        f"--grpc_python_out={STUBS_DIR}",
        str(proto),
    ]
    status = protoc.main(args)
    if status != 0:
        sys.exit(f"jsae: protoc failed on {proto} (exit status {status})")

    grpc_module = STUBS_DIR / "jsae_pb2_grpc.py"
    text = grpc_module.read_text(encoding="utf-8")
    fixed, count = TOP_LEVEL_IMPORT.subn("from . import jsae_pb2 as ", text)
    if count != 1:
        sys.exit(
            f"jsae: expected one `import jsae_pb2 as ...` line in {grpc_module}, found "
            f"{count}; has grpcio-tools changed what it generates?"
        )
    grpc_module.write_text(fixed, encoding="utf-8")


class BuildPyWithStubs(build_py):
    """`build_py` that generates the gRPC stubs before collecting the package's modules."""

    def run(self) -> None:
        generate_stubs()
        super().run()


setup(cmdclass={"build_py": BuildPyWithStubs})
