"""Fixtures for the package's tests: the `jsae` binary and real Recommender services.

The binary is `$JSAE_BIN`, else the workspace's target/release/jsae, else target/debug/jsae;
without one the tests that need a service are skipped (build it with `cargo build --release`).
A service listens on 127.0.0.1 port 0 and its first stdout line says where (the announcement
jsae_net::logging::announce_listening prints, text or JSON); the tests connect at once.
"""

from __future__ import annotations

import json
import os
import queue
import secrets
import shutil
import subprocess
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator, List, Optional

import pytest

PYTHON_DIR = Path(__file__).resolve().parents[1]
REPO_ROOT = PYTHON_DIR.parent

#: How long a service may take to announce its address, in seconds.
START_TIMEOUT_S = 120.0

#: Settings for a Recommender that needs no data files and no run: 40 synthetic items
#: (`item-0` .. `item-39`) and sessions drawn over them.
SYNTHETIC_SETTINGS = """\
env = "recommender"
[environment.recommender]
source = "synthetic"
[environment.recommender.synthetic]
items = 40
sessions = 500
"""


def find_jsae_binary() -> Path:
    """The `jsae` binary to test against; skips the test when there is none."""
    chosen = os.environ.get("JSAE_BIN")
    if chosen:
        path = Path(chosen)
        if not path.is_file():
            pytest.fail(f"JSAE_BIN={chosen} is not a file")
        return path
    candidates = [REPO_ROOT / "target" / profile / "jsae" for profile in ("release", "debug")]
    for path in candidates:
        if path.is_file():
            return path
    pytest.skip(
        "no jsae binary: set JSAE_BIN or build one (`cargo build --release`); looked at "
        + ", ".join(str(p) for p in candidates)
    )


def announced_address(line: str) -> Optional[str]:
    """The address in a service's announcement line ("NAME listening on ADDR", or a JSON
    log event with `fields.address`), None when the line is no announcement."""
    text = line.strip()
    if text.startswith("{"):
        try:
            return json.loads(text)["fields"]["address"]
        except (ValueError, KeyError, TypeError):
            return None
    last = text.rsplit(" ", 1)[-1]
    return last if "listening on" in text and ":" in last else None


@dataclass
class RunningService:
    """A `jsae recommender` process started by a test, and where it listens."""

    process: subprocess.Popen
    address: str
    stderr_path: Path

    @property
    def port(self) -> int:
        """The port it listens on."""
        return int(self.address.rsplit(":", 1)[1])

    def stderr(self) -> str:
        """What it wrote on stderr so far (its logs)."""
        return self.stderr_path.read_text(errors="replace")

    def stop(self) -> None:
        """Stops it with SIGTERM (SIGKILL if it has not exited after 20 s)."""
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


def _drain(stream, lines: "queue.Queue[str]") -> None:
    """Passes each stdout line on, so the service never blocks on a full pipe."""
    for line in stream:
        lines.put(line)
    lines.put("")


def start_recommender(binary: Path, work: Path, extra: List[str]) -> RunningService:
    """Starts `jsae recommender --policy popular` on the synthetic settings with `extra`
    flags, listening on a free loopback port, and waits for its announcement."""
    settings = work / "recommender.toml"
    settings.write_text(SYNTHETIC_SETTINGS)
    stderr_path = work / f"recommender-{len(list(work.glob('recommender-*.log')))}.log"
    # the service reads JSAE_* variables as flag fallbacks: keep the caller's out of the test
    env = {k: v for k, v in os.environ.items() if not k.startswith("JSAE_")}
    args = [str(binary), "recommender", "--listen", "127.0.0.1:0", "--policy", "popular",
            "--config", str(settings), *extra]
    with open(stderr_path, "wb") as stderr:
        process = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=stderr,
                                   stdin=subprocess.DEVNULL, env=env, text=True, cwd=work)
    lines: "queue.Queue[str]" = queue.Queue()
    threading.Thread(target=_drain, args=(process.stdout, lines), daemon=True).start()
    try:
        first = lines.get(timeout=START_TIMEOUT_S)
    except queue.Empty:
        first = None
    address = announced_address(first) if first else None
    if address is None:
        process.kill()
        process.wait()
        pytest.fail(
            f"`{' '.join(args)}` did not announce an address (first line {first!r}, exit "
            f"status {process.returncode}); stderr:\n{stderr_path.read_text(errors='replace')}"
        )
    return RunningService(process=process, address=address, stderr_path=stderr_path)


@pytest.fixture
def recommender_service(tmp_path: Path) -> Iterator[Callable[..., RunningService]]:
    """A function starting Recommender services (`extra` flags); all stop after the test."""
    binary = find_jsae_binary()
    started: List[RunningService] = []

    def start(*extra: str) -> RunningService:
        service = start_recommender(binary, tmp_path, list(extra))
        started.append(service)
        return service

    yield start
    for service in started:
        service.stop()


@pytest.fixture
def token_file(tmp_path: Path) -> Path:
    """A fresh deployment token (32 hex characters) in a file, as `--auth-token-file` takes."""
    path = tmp_path / "token"
    path.write_text(secrets.token_hex(16) + "\n")
    return path


@dataclass
class Pki:
    """A throw-away CA and a server certificate it signed for `localhost` (PEM files)."""

    ca: Path
    cert: Path
    key: Path


@pytest.fixture
def pki(tmp_path: Path) -> Pki:
    """A CA and a `localhost` server certificate made with the openssl command (the test is
    skipped without it). The certificate names only DNS `localhost`, not 127.0.0.1."""
    openssl = shutil.which("openssl")
    if openssl is None:
        pytest.skip("no openssl command to make a test CA")
    work = tmp_path / "pki"
    work.mkdir()
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
    steps = [
        ["req", "-x509", *ec, "-keyout", "ca.key", "-out", "ca.pem", "-days", "2",
         "-subj", "/CN=jsae python test CA",
         "-addext", "basicConstraints=critical,CA:TRUE",
         "-addext", "keyUsage=critical,keyCertSign,cRLSign"],
        ["req", *ec, "-keyout", "server.key", "-out", "server.csr", "-subj", "/CN=localhost"],
        ["x509", "-req", "-in", "server.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
         "-CAcreateserial", "-out", "server.pem", "-days", "2", "-extfile", "server.ext"],
    ]
    (work / "server.ext").write_text(
        "basicConstraints=CA:FALSE\nkeyUsage=critical,digitalSignature\n"
        "extendedKeyUsage=serverAuth\nsubjectAltName=DNS:localhost\n"
    )
    for step in steps:
        done = subprocess.run([openssl, *step], cwd=work, capture_output=True, text=True,
                              stdin=subprocess.DEVNULL)
        if done.returncode != 0:
            pytest.fail(f"openssl {' '.join(step)}: {done.stderr}")
    return Pki(ca=work / "ca.pem", cert=work / "server.pem", key=work / "server.key")
