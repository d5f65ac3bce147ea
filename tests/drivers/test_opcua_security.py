"""OPC UA security: Basic256Sha256 SignAndEncrypt with a user name and
password against the simulated server, server-certificate pinning and trust
store, and the configurations refused before any connection.

Certificates (a CA, the server, the client, a rogue server) are made at test
time with `cryptography`, once per module."""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import pytest_asyncio
from pydantic import ValidationError

from drivers.backoff import Backoff
from drivers.base import Quality
from drivers.errors import ConnectionLost
from drivers.opcua import OpcUaDriver
from drivers.opcua_security import OpcUaSecurity, SecurityRejected
from drivers.sim.opcua_server import OpcUaSimController, OpcUaSimSecurity
from tests.pki import make_cert, name, new_key, write_cert, write_key

pytestmark = pytest.mark.asyncio(loop_scope="module")

USER = "operator"
PASSWORD = "s3cret-Pa55word"
WRONG_PASSWORD = "guessed-Pa55word"
SERVER_URI = "urn:compd:sim:server"
CLIENT_URI = "urn:compd:test:client"


@dataclass(frozen=True)
class Pki:
    ca: Path
    server_cert: Path
    server_key: Path
    client_cert: Path
    client_key: Path
    rogue_cert: Path
    trust_dir: Path


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    d = tmp_path_factory.mktemp("pki")
    ca_key, server_key, client_key = new_key(), new_key(), new_key()
    ca_cert = make_cert("compd test CA", ca_key, name("compd test CA"), ca_key, ca=True)
    server_cert = make_cert("sim server", server_key, ca_cert.subject, ca_key, uri=SERVER_URI)
    client_cert = make_cert("compd client", client_key, ca_cert.subject, ca_key, uri=CLIENT_URI)
    # same subject and key, but self-signed: a different certificate (an impostor)
    rogue_cert = make_cert("sim server", server_key, name("sim server"), server_key,
                       uri=SERVER_URI)
    trust_dir = d / "trusted"
    trust_dir.mkdir()
    return Pki(ca=write_cert(trust_dir / "ca.der", ca_cert),
               server_cert=write_cert(d / "server.der", server_cert),
               server_key=write_key(d / "server.pem", server_key),
               client_cert=write_cert(d / "client.der", client_cert),
               client_key=write_key(d / "client.pem", client_key),
               rogue_cert=write_cert(d / "rogue.der", rogue_cert),
               trust_dir=trust_dir)


@pytest_asyncio.fixture(loop_scope="module", scope="module")
async def sim(pki: Pki) -> AsyncIterator[OpcUaSimController]:
    controller = OpcUaSimController(security=OpcUaSimSecurity(
        certificate=pki.server_cert, private_key=pki.server_key,
        policies=("Basic256Sha256_SignAndEncrypt",), users={USER: PASSWORD},
        application_uri=SERVER_URI))
    await controller.start()
    try:
        yield controller
    finally:
        await controller.stop()


def _security(pki: Pki, **changes: object) -> OpcUaSecurity:
    fields: dict[str, object] = {
        "policy": "Basic256Sha256", "mode": "SignAndEncrypt",
        "certificate": pki.client_cert, "private_key": pki.client_key,
        "server_certificate": pki.server_cert, "username": USER, "password": PASSWORD}
    fields.update(changes)
    return OpcUaSecurity.model_validate(fields)


def _driver(sim: OpcUaSimController, security: OpcUaSecurity) -> OpcUaDriver:
    return OpcUaDriver(sim.endpoint, dict(sim.channels),  # type: ignore[arg-type]
                       dict(sim.outputs_map), timeout_s=1.0,  # type: ignore[arg-type]
                       backoff=Backoff(initial_s=0.02, cap_s=0.1), security=security)


async def test_pinned_server_and_right_password_connect_readwrite_cert(
        sim: OpcUaSimController, pki: Pki) -> None:
    await sim.publish({"bearing": 33.5})
    driver = _driver(sim, _security(pki))
    try:
        await driver.connect()
        samples = await driver.read(["bearing", "ambient"])
        await driver.write({"offset": -4.5})
    finally:
        await driver.close()
    assert samples["bearing"].value == 33.5
    assert samples["bearing"].quality is Quality.GOOD
    assert (await sim.outputs())["offset"] == -4.5


async def test_password_never_reaches_the_logs(sim: OpcUaSimController, pki: Pki,
                                               caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG)
    caplog.set_level(logging.DEBUG, logger="asyncua")  # the daemon floors it at WARNING
    driver = _driver(sim, _security(pki))
    try:
        await driver.read(["ambient"])
    finally:
        await driver.close()
    assert "ActivateSessionRequest, redacted" in caplog.text  # asyncua did log it
    assert PASSWORD not in caplog.text
    assert PASSWORD.encode().hex() not in caplog.text


async def test_trust_store_with_the_ca_connects(sim: OpcUaSimController, pki: Pki) -> None:
    driver = _driver(sim, _security(pki, server_certificate=None, trust_store=pki.trust_dir))
    try:
        await driver.read(["ambient"])
    finally:
        await driver.close()


async def test_wrong_password_refused_without_echoing_it(
        sim: OpcUaSimController, pki: Pki) -> None:
    security = _security(pki, password=WRONG_PASSWORD)
    driver = _driver(sim, security)
    try:
        with pytest.raises(SecurityRejected) as caught:
            await driver.connect()
    finally:
        await driver.close()
    assert isinstance(caught.value, ConnectionLost)
    message = str(caught.value)
    assert USER in message
    assert WRONG_PASSWORD not in message and PASSWORD not in message
    assert WRONG_PASSWORD not in repr(security) and WRONG_PASSWORD not in str(security)
    assert not driver.connected


async def test_wrong_pinned_certificate_refused(sim: OpcUaSimController, pki: Pki) -> None:
    driver = _driver(sim, _security(pki, server_certificate=pki.rogue_cert))
    try:
        with pytest.raises(SecurityRejected, match="not the pinned certificate"):
            await driver.read(["ambient"])
    finally:
        await driver.close()


async def test_untrusted_server_refused_by_trust_store(
        sim: OpcUaSimController, pki: Pki, tmp_path: Path) -> None:
    other = tmp_path / "other"
    other.mkdir()
    (other / "rogue.der").write_bytes(pki.rogue_cert.read_bytes())
    driver = _driver(sim, _security(pki, server_certificate=None, trust_store=other))
    try:
        with pytest.raises(SecurityRejected, match="not trusted"):
            await driver.connect()
    finally:
        await driver.close()


async def test_policy_the_server_does_not_offer_is_refused(
        sim: OpcUaSimController, pki: Pki) -> None:
    driver = _driver(sim, _security(pki, policy="Aes256_Sha256_RsaPss"))
    try:
        with pytest.raises(SecurityRejected, match="offers no endpoint"):
            await driver.connect()
    finally:
        await driver.close()


async def test_password_with_policy_none_refused(pki: Pki) -> None:
    with pytest.raises(ValidationError, match="policy None") as caught:
        OpcUaSecurity(policy="None", username=USER, password=PASSWORD)
    assert PASSWORD not in str(caught.value)
    assert PASSWORD not in repr(caught.value)


@pytest.mark.parametrize("policy", ["Basic128Rsa15", "Basic256"])
async def test_deprecated_policies_refused(pki: Pki, policy: str) -> None:
    with pytest.raises(ValidationError, match="deprecated"):
        _security(pki, policy=policy)


async def test_secured_policy_needs_a_way_to_trust_the_server(pki: Pki) -> None:
    with pytest.raises(ValidationError, match="pin the server certificate"):
        _security(pki, server_certificate=None)
    with pytest.raises(ValidationError, match="client certificate"):
        _security(pki, certificate=None)
