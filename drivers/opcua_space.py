"""The OPC UA standard address space, built once per process and copied into
every OPC UA server this process starts: the simulated controllers
(`drivers.sim.opcua_server`) and the daemon's own face (`compd.faces.opcua_face`).

asyncua fills a new server's address space (about 6000 nodes of the OPC UA
standard) by adding node after node, about a second of CPU per server. The
simulated controllers start hundreds of times in a test run, a bench may
start several, and the tests start the daemon's face a few dozen times:
`CopiedSpaceInternalServer` builds it once
(`standard_address_space.fill_address_space`, as asyncua does) and gives
every later server its own copy, which takes a tenth of the time. The
template is only read once built; two threads that start the first servers
together may both build it, and either result is the same.

What a server may change is copied; what it only replaces is shared:

- per node, the `NodeData`, its attributes dict, each `AttributeValue` (a
  write replaces ``.value``, a subscription adds to ``datachange_callbacks``)
  and its references list (AddReferences/DeleteReferences append and remove);
- a value whose variant holds a list (NamespaceArray, ServerArray: asyncua
  appends a namespace to the list it read) gets its own list.

`DataValue`, `Variant` and the node ids, names and reference descriptions
are shared between the copies: asyncua replaces a value on write and never
changes one in place, except a reference description's names when a node of
the standard is renamed, which nothing here does.
"""

from __future__ import annotations

import asyncio
import dataclasses
from pathlib import Path

from asyncua import ua
from asyncua.server.address_space import (
    AddressSpace,
    AttributeValue,
    NodeData,
    NodeManagementService,
)
from asyncua.server.internal_server import InternalServer

__all__ = ["CopiedSpaceInternalServer", "standard_nodes"]

_template: dict[ua.NodeId, NodeData] | None = None
_PLACEHOLDER = ua.DataValue()


def _build() -> dict[ua.NodeId, NodeData]:
    from asyncua.server.standard_address_space import standard_address_space

    aspace = AddressSpace()
    standard_address_space.fill_address_space(  # type: ignore[no-untyped-call]
        NodeManagementService(aspace))
    return dict(aspace._nodes)  # asyncua keeps the nodes in this dict


def _own_value(av: AttributeValue) -> AttributeValue:
    """A fresh AttributeValue holding the same value; a list value copied."""
    dv = av.value
    if dv is not None and dv.Value is not None and isinstance(dv.Value.Value, list):
        variant = dataclasses.replace(dv.Value, Value=list(dv.Value.Value))
        dv = dataclasses.replace(dv, Value=variant)
    mine = AttributeValue(_PLACEHOLDER)  # the constructor wants a DataValue, not None
    mine.value = dv
    return mine


def _copy(nodes: dict[ua.NodeId, NodeData]) -> dict[ua.NodeId, NodeData]:
    out: dict[ua.NodeId, NodeData] = {}
    for nodeid, node in nodes.items():
        mine = NodeData(nodeid)
        mine.attributes = {attr: _own_value(av) for attr, av in node.attributes.items()}
        mine.references = list(node.references)
        out[nodeid] = mine
    return out


async def standard_nodes() -> dict[ua.NodeId, NodeData]:
    """A fresh copy of the standard address space (built on the first call, in
    a worker thread as asyncua builds it, so the event loop keeps serving)."""
    global _template  # noqa: PLW0603 -- the one per-process cache of this module
    if _template is None:
        _template = await asyncio.to_thread(_build)
    return _copy(_template)


class CopiedSpaceInternalServer(InternalServer):
    """asyncua's InternalServer with the standard address space copied from
    the per-process template instead of filled node by node; everything else
    of `Server.init` (namespace array, server status, build info) as asyncua
    does it, on the copy."""

    async def load_standard_address_space(self, shelf_file: Path | None = None) -> None:
        self.aspace._nodes = await standard_nodes()
