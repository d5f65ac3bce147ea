"""The OPC UA standard address space, built once per process and shared by
every OPC UA server this process starts: the simulated controllers
(`drivers.sim.opcua_server`) and the daemon's own face (`compd.faces.opcua_face`).

asyncua fills a new server's address space (about 6000 nodes of the OPC UA
standard) by adding node after node, about a second of CPU and some 40 MB per
server. The simulated controllers start hundreds of times in a test run, a
fleet benchmark starts hundreds in one process, and the tests start the
daemon's face a few dozen times: `CopiedSpaceInternalServer` builds the
standard space once per process (`standard_address_space.fill_address_space`,
as asyncua does, under a lock, so servers started together wait for the one
build) and gives every server a `SharedNodes` over it.

`SharedNodes` is the server's node table: every node id of the standard maps
to the template's node until the server first looks that node up, and the
lookup gives the server its own copy from then on. A server can only change a
node it has looked up (asyncua's services, its own start-up and a client's
requests all reach a node through a lookup), so a node a server has never
looked up is one it has not changed and can share. A simulated controller
looks up some hundred standard nodes in its life (server status, namespace
array, capabilities, what a client browses); the other thousands stay shared.

A copy holds what a server may change, copied: the `NodeData`, its attributes
dict, each `AttributeValue` (a write replaces ``.value``, a subscription adds to
``datachange_callbacks``), its references list (AddReferences/DeleteReferences
append and remove), and a value whose variant holds a list (NamespaceArray,
ServerArray: asyncua appends a namespace to the list it read) gets its own
list. `DataValue`, `Variant` and the node ids, names and reference
descriptions are shared: asyncua replaces a value on write and never changes
one in place, except a reference description's names when a node of the
standard is renamed, which nothing here does.
"""

from __future__ import annotations

import asyncio
import dataclasses
import threading
from pathlib import Path

from asyncua import ua
from asyncua.server.address_space import (
    AddressSpace,
    AttributeValue,
    NodeData,
    NodeManagementService,
)
from asyncua.server.internal_server import InternalServer

__all__ = ["CopiedSpaceInternalServer", "SharedNodes", "standard_nodes"]

_template: dict[ua.NodeId, NodeData] | None = None
_template_lock = threading.Lock()
_PLACEHOLDER = ua.DataValue()


def _build() -> dict[ua.NodeId, NodeData]:
    from asyncua.server.standard_address_space import standard_address_space

    aspace = AddressSpace()
    standard_address_space.fill_address_space(  # type: ignore[no-untyped-call]
        NodeManagementService(aspace))
    return dict(aspace._nodes)  # asyncua keeps the nodes in this dict


def _built() -> dict[ua.NodeId, NodeData]:
    """The process's template, built by the first caller; the others wait for it."""
    global _template  # noqa: PLW0603 -- the one per-process cache of this module
    with _template_lock:
        if _template is None:
            _template = _build()
        return _template


def _own_value(av: AttributeValue) -> AttributeValue:
    """A fresh AttributeValue holding the same value; a list value copied."""
    dv = av.value
    if dv is not None and dv.Value is not None and isinstance(dv.Value.Value, list):
        variant = dataclasses.replace(dv.Value, Value=list(dv.Value.Value))
        dv = dataclasses.replace(dv, Value=variant)
    mine = AttributeValue(_PLACEHOLDER)  # the constructor wants a DataValue, not None
    mine.value = dv
    mine.value_callback = av.value_callback
    mine.value_setter = av.value_setter
    return mine


def _own_node(node: NodeData) -> NodeData:
    mine = NodeData(node.nodeid)
    mine.attributes = {attr: _own_value(av) for attr, av in node.attributes.items()}
    mine.references = list(node.references)
    mine.call = node.call
    return mine


class SharedNodes(dict[ua.NodeId, NodeData]):
    """One server's node table over the shared standard template: a node is
    copied for this server the first time it is looked up (module docstring).

    Membership, length, keys, adding and deleting are the plain dict's; every
    way of getting a node out (`[]`, `get`, `values`, `items`, `pop`,
    `setdefault`) hands out this server's own copy."""

    def __init__(self, template: dict[ua.NodeId, NodeData]) -> None:
        super().__init__(template)
        self._template = template

    def _own(self, nodeid: ua.NodeId, node: NodeData) -> NodeData:
        if node is self._template.get(nodeid):
            node = _own_node(node)
            dict.__setitem__(self, nodeid, node)
        return node

    def __getitem__(self, nodeid: ua.NodeId) -> NodeData:
        return self._own(nodeid, dict.__getitem__(self, nodeid))

    def get(self, nodeid: ua.NodeId, default: NodeData | None = None  # type: ignore[override]
            ) -> NodeData | None:
        node = dict.get(self, nodeid)
        return default if node is None else self._own(nodeid, node)

    def setdefault(self, nodeid: ua.NodeId, default: NodeData) -> NodeData:
        if nodeid in self:
            return self[nodeid]
        dict.__setitem__(self, nodeid, default)
        return default

    def pop(self, nodeid: ua.NodeId, *default: NodeData) -> NodeData:  # type: ignore[override]
        if nodeid not in self and default:
            return default[0]
        node = self[nodeid]
        dict.__delitem__(self, nodeid)
        return node

    def popitem(self) -> tuple[ua.NodeId, NodeData]:
        nodeid, node = dict.popitem(self)
        return nodeid, self._own(nodeid, node)

    def values(self) -> list[NodeData]:  # type: ignore[override]
        return [self[k] for k in list(self.keys())]

    def items(self) -> list[tuple[ua.NodeId, NodeData]]:  # type: ignore[override]
        return [(k, self[k]) for k in list(self.keys())]

    def copy(self) -> dict[ua.NodeId, NodeData]:
        return dict(self.items())

    def shared(self) -> int:
        """How many nodes this server still shares with the template."""
        template = self._template
        return sum(1 for k, node in dict.items(self) if node is template.get(k))


async def standard_nodes() -> SharedNodes:
    """A server's own view of the standard address space (built on the first
    call, in a worker thread as asyncua builds it, so the event loop keeps
    serving)."""
    template = _template
    if template is None:
        template = await asyncio.to_thread(_built)
    return SharedNodes(template)


class CopiedSpaceInternalServer(InternalServer):
    """asyncua's InternalServer with the standard address space shared from
    the per-process template (`SharedNodes`) instead of filled node by node;
    everything else of `Server.init` (namespace array, server status, build
    info) as asyncua does it, on this server's own copies of those nodes."""

    async def load_standard_address_space(self, shelf_file: Path | None = None) -> None:
        self.aspace._nodes = await standard_nodes()
