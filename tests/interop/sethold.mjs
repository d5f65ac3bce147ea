// A node-opcua client against compd's OPC UA face: read the machine's
// Heartbeat and FaultStateName, call SetHold(true), read OperatorHold.
// Usage: node sethold.mjs ENDPOINT MACHINE USER PASSWORD PKI_DIR
// Prints one JSON line; exits 1 with a JSON error line on failure.
import {
  OPCUAClient, MessageSecurityMode, SecurityPolicy, AttributeIds, DataType, UserTokenType,
} from "node-opcua-client";
import { OPCUACertificateManager } from "node-opcua-certificate-manager";

const [endpoint, machine, user, password, pkiDir] = process.argv.slice(2);

async function main() {
  const certificateManager = new OPCUACertificateManager({
    rootFolder: pkiDir, automaticallyAcceptUnknownCertificate: true,
  });
  const client = OPCUAClient.create({
    applicationName: "compd-interop-node-opcua",
    applicationUri: "urn:compd:test:node-opcua",
    securityMode: MessageSecurityMode.SignAndEncrypt,
    securityPolicy: SecurityPolicy.Basic256Sha256,
    endpointMustExist: false,
    connectionStrategy: { maxRetry: 0, initialDelay: 100 },
    clientCertificateManager: certificateManager,
  });
  await client.connect(endpoint);
  try {
    const session = await client.createSession({
      type: UserTokenType.UserName, userName: user, password,
    });
    const ns = (await session.readNamespaceArray()).indexOf("urn:compd");
    const id = (path) => `ns=${ns};s=${machine}.${path}`;
    const read = async (path) =>
      (await session.read({ nodeId: id(path), attributeId: AttributeIds.Value })).value.value;
    const heartbeat = await read("Heartbeat");
    const state = await read("FaultStateName");
    const result = await session.call({
      objectId: id("Machine"), methodId: id("SetHold"),
      inputArguments: [{ dataType: DataType.Boolean, value: true }],
    });
    await new Promise((r) => setTimeout(r, 300));
    const hold = await read("OperatorHold");
    console.log(JSON.stringify({
      ns, heartbeat, state, call: result.statusCode.name,
      output: result.outputArguments.map((v) => v.value), hold,
    }));
    await session.close();
  } finally {
    await client.disconnect();
  }
}

main().catch((err) => {
  console.log(JSON.stringify({ error: String(err && err.message || err) }));
  process.exit(1);
});
